"""The study's method on whole cycles of a rig that records no command (docs/rigs.md, issue 17).

The study judges a window by the distribution of each sensor's prediction errors under a *healthy reference
model* driven by the command, compared by relative entropy with each condition's base error distribution
(Eq. 5.3). A rig that repeats one fixed load cycle (the UCI rig) records no command; here the inputs of a
sensor's reference model are

- the **second of the cycle**, through the healthy mean profile: every channel's mean over the healthy training
  cycles at that second (the fixed load cycle is the command, so its time carries what the command would), and
- the **other channels at the same second**, as deviations from their healthy profile (they carry the operating
  condition: oil temperature, the other components' states).

Per sensor ``s``: ``x_s(t) - m_s(t) = Σ_j β_sj (x_j(t) - m_j(t)) + e_s(t)`` (ridge, channels standardised, fitted
on the healthy training cycles); a cycle's errors are summarised by a Gaussian ``N(μ, σ²)``; each condition ``k``
has a base error distribution ``N(μ_k, σ_k²)`` (its training cycles' errors pooled); the features are
``log D(cycle ‖ k)`` for every sensor and condition, with the Gaussian relative entropy
``D = log(σ_k / σ) + (σ² + (μ - μ_k)²) / (2 σ_k²) - 1/2`` (nats).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.errors import NotFittedError, ParameterError

FLOOR = 1e-12
"""Smallest relative entropy and error spread kept (the log of 0 is not a feature), nats and the sensor's unit."""


def gaussian_relative_entropy(mu: np.ndarray, sigma: np.ndarray, mu_k: np.ndarray, sigma_k: np.ndarray) -> np.ndarray:
    """``D(N(mu, sigma²) ‖ N(mu_k, sigma_k²))``, nats, elementwise (broadcast)."""
    return np.log(sigma_k / sigma) + (sigma**2 + (mu - mu_k) ** 2) / (2 * sigma_k**2) - 0.5


class CycleReferenceEntropy:
    """Relative entropies of each sensor's reference-model errors against each condition's (module docstring).

    Parameters
    ----------
    healthy : str or float
        The judged component's healthy label: its training cycles fit the reference models.
    sensors : sequence of int or None, default None
        Channels (axis 1) that get a reference model; None: every channel. Every channel is an input.
    alpha : float, default 1.0
        Ridge penalty on the standardised inputs (in units of the healthy samples' count over 1000).
    """

    def __init__(self, *, healthy: str | float, sensors: Sequence[int] | None = None, alpha: float = 1.0) -> None:
        self.healthy = healthy
        self.sensors = sensors
        self.alpha = alpha

    def fit(self, values: np.ndarray, labels: np.ndarray) -> CycleReferenceEntropy:
        """Fit the reference models on the healthy cycles of ``values`` (n_cycles, n_channels, n_samples), then each
        condition's base error distribution on its cycles."""
        if values.ndim != 3 or self.alpha < 0:
            raise ParameterError(f"values must have shape (cycles, channels, samples) and alpha >= 0. Got shape "
                                 f"{values.shape}, alpha={self.alpha}.")
        healthy = labels == self.healthy
        if healthy.sum() < 2:
            raise ParameterError(f"the training cycles must hold >= 2 of the healthy state {self.healthy!r} to fit "
                                 f"reference models. Got {int(healthy.sum())}.")
        chosen = range(values.shape[1]) if self.sensors is None else self.sensors
        self.sensors_ = np.asarray(list(chosen), dtype=int)
        self.profile_ = values[healthy].mean(axis=0)
        deviations = values[healthy] - self.profile_
        self.scale_ = np.where(deviations.std(axis=(0, 2)) > 0, deviations.std(axis=(0, 2)), 1.0)
        z = np.moveaxis(deviations / self.scale_[None, :, None], 1, 2).reshape(-1, values.shape[1])
        penalty = self.alpha * z.shape[0] / 1000.0
        coefficients = []
        for s in self.sensors_:
            inputs = np.delete(z, s, axis=1)
            gram = inputs.T @ inputs + penalty * np.eye(inputs.shape[1])
            coefficients.append(np.insert(np.linalg.solve(gram, inputs.T @ z[:, s]), s, 0.0))
        self.coefficients_ = np.asarray(coefficients)
        self.classes_ = np.unique(labels)
        errors = self.errors(values)
        self.base_mean_ = np.stack([errors[labels == k].mean(axis=(0, 2)) for k in self.classes_])
        self.base_std_ = np.stack([np.maximum(errors[labels == k].std(axis=(0, 2)), FLOOR) for k in self.classes_])
        return self

    def errors(self, values: np.ndarray) -> np.ndarray:
        """Each sensor's prediction errors, standardised, shape (n_cycles, n_sensors, n_samples)."""
        if not hasattr(self, "coefficients_"):
            raise NotFittedError("CycleReferenceEntropy must be fitted before errors. Call fit first.")
        z = (values - self.profile_) / self.scale_[None, :, None]
        predicted = np.einsum("sc,nct->nst", self.coefficients_, z)
        return np.asarray(z[:, self.sensors_, :] - predicted)

    def transform(self, values: np.ndarray) -> np.ndarray:
        """``log D`` of every sensor against every condition, shape (n_cycles, n_sensors * n_classes)."""
        e = self.errors(values)
        mu, sigma = e.mean(axis=2)[:, :, None], np.maximum(e.std(axis=2), FLOOR)[:, :, None]
        d = gaussian_relative_entropy(mu, sigma, self.base_mean_.T[None], self.base_std_.T[None])
        return np.log(np.maximum(d, FLOOR)).reshape(len(values), -1)

    def to_state(self) -> dict[str, Any]:
        """Parameters and fitted arrays (:mod:`hydrowatch.cycles.state`)."""
        if not hasattr(self, "coefficients_"):
            raise NotFittedError("CycleReferenceEntropy must be fitted before to_state. Call fit first.")
        return {"healthy": self.healthy, "sensors": None if self.sensors is None else [int(s) for s in self.sensors],
                "alpha": self.alpha, "sensors_": self.sensors_, "profile_": self.profile_, "scale_": self.scale_,
                "coefficients_": self.coefficients_, "classes_": self.classes_, "base_mean_": self.base_mean_,
                "base_std_": self.base_std_}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> CycleReferenceEntropy:
        """The inverse of :meth:`to_state`."""
        out = cls(healthy=state["healthy"], sensors=state["sensors"], alpha=state["alpha"])
        for name in ("sensors_", "profile_", "scale_", "coefficients_", "classes_", "base_mean_", "base_std_"):
            setattr(out, name, state[name])
        return out
