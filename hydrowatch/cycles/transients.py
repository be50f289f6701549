"""Features that isolate a slow component's physics: transients at the cycle's load changes, with the
other components' influence projected out.

Why (docs/rigs.md): a hydraulic accumulator shows itself in how fast the pressures settle after a
load change (its gas precharge sets the circuit's hydraulic capacitance), not in the cycle's
levels, which the cooler, the valve and the oil temperature move far more. On a grid of 1 s block
means the second that holds a load change keeps the transient's integral, so the value of each
channel in the seconds around each change, relative to the level it settles at, carries it.
Other components' conditions still move those values; :class:`NuisanceProjection` removes the
feature directions along which they do (within each class of the judged component, learnt from
the training cycles only), so a classifier cannot lean on a cooler state that happens to go with
an accumulator state in training.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.errors import NotFittedError, ParameterError


def load_changes(profile: np.ndarray, threshold: float) -> np.ndarray:
    """Samples at which a cycle's mean profile jumps: ``|profile[s] - profile[s - 1]| > threshold``.

    A change spread over consecutive samples (a 1 s grid cuts a transient in two) counts once, at
    its first sample.

    Parameters
    ----------
    profile : ndarray, shape (n_samples,)
        Mean over cycles of a channel that follows the load (e.g. the system pressure, bar).
    threshold : float
        Smallest jump counted, in the channel's unit.

    Returns
    -------
    ndarray of int
        Indices ``s`` (the first sample after each change), ascending.
    """
    if threshold <= 0:
        raise ParameterError(f"threshold must be > 0. Got {threshold}.")
    jumps = np.flatnonzero(np.abs(np.diff(profile)) > threshold) + 1
    return jumps[np.r_[True, np.diff(jumps) > 1]] if jumps.size else jumps


class LoadChangeTransients:
    """Values of every channel around each load change, relative to the level it settles at.

    For a change at sample ``s`` and each channel ``x``: ``x[s + k] - mean(x[s + a : s + b])`` for
    ``k`` in ``-before .. after - 1``, with ``(a, b) = settle``. Changes too close to the cycle's
    ends for this window are skipped.

    Parameters
    ----------
    reference : int, default 0
        Channel (axis 1 of the values) whose mean profile locates the load changes.
    threshold : float, default 3.0
        Smallest jump of the reference's mean profile that counts as a load change, in its unit.
    before, after : int, default 1, 2
        Samples before and from each change that become features.
    settle : tuple of int, default (2, 4)
        Samples after the change, ``[a, b)``, whose mean is the settled level.
    channels : sequence of int or None, default None
        Channels whose transients are features; None: every channel.
    normalised : bool, default False
        Also give, for each (channel, change) with a clear step, the same samples as a share of the
        cycle's own step: ``(x[s + k] - settled) / (before_level - settled)``, dimensionless, where
        ``before_level`` is the mean of the two samples before the first feature sample, the step bounded to
        ``[1/2, 2]`` times its median over the training cycles (a cycle whose step is missing, which happens on
        a real rig, stays finite). A change whose
        time constant or step height scales with the operating condition (oil viscosity, load) moves
        the plain values in proportion; the share of the step not yet completed in the sample that holds
        the change cancels the step height, and with it much of that condition.
    clear_step : float, default 10.0
        A (channel, change) is normalised when, over the training cycles, the median step exceeds
        ``clear_step`` times the median absolute deviation of the steps and no cycle's step is 0.
    """

    def __init__(
        self,
        *,
        reference: int = 0,
        threshold: float = 3.0,
        before: int = 1,
        after: int = 2,
        settle: tuple[int, int] = (2, 4),
        channels: Sequence[int] | None = None,
        normalised: bool = False,
        clear_step: float = 10.0,
    ) -> None:
        self.reference = reference
        self.threshold = threshold
        self.before = before
        self.after = after
        self.settle = settle
        self.channels = channels
        self.normalised = normalised
        self.clear_step = clear_step

    def fit(self, values: np.ndarray) -> LoadChangeTransients:
        """Locate the load changes on the training cycles, shape (n_cycles, n_channels, n_samples)."""
        if values.ndim != 3 or not 0 <= self.reference < values.shape[1]:
            raise ParameterError(
                f"values must have shape (cycles, channels, samples) with channel {self.reference}. "
                f"Got shape {values.shape}."
            )
        if self.before < 0 or self.after < 1 or not 0 < self.settle[0] < self.settle[1]:
            raise ParameterError(
                f"before must be >= 0, after >= 1 and settle (a, b) with 0 < a < b. Got "
                f"before={self.before}, after={self.after}, settle={self.settle}."
            )
        chosen = range(values.shape[1]) if self.channels is None else self.channels
        if not chosen or not all(0 <= c < values.shape[1] for c in chosen):
            raise ParameterError(f"channels must be indices of the {values.shape[1]} channels. Got {self.channels}.")
        self.channels_ = np.asarray(list(chosen), dtype=int)
        changes = load_changes(values[:, self.reference, :].mean(axis=0), self.threshold)
        n = values.shape[2]
        self.changes_ = changes[(changes - self.before >= 0) & (changes + self.settle[1] <= n)]
        if self.changes_.size == 0:
            raise ParameterError(
                f"the reference channel's mean profile must change by more than threshold="
                f"{self.threshold} somewhere inside the cycle. Got no such change; lower it."
            )
        self.steps_, self.typical_steps_ = np.zeros((0, 2), dtype=int), np.zeros(0)
        if self.normalised:
            if self.clear_step <= 0:
                raise ParameterError(f"clear_step must be > 0. Got {self.clear_step}.")
            pairs = [(c, s) for c in self.channels_ for s in self.changes_ if s - self.before - 2 >= 0]
            self.steps_ = np.array([(c, s) for c, s in pairs if self._clear(self._step(values, c, s))],
                                   dtype=int).reshape(-1, 2)
            self.typical_steps_ = np.array([np.median(self._step(values, c, s)) for c, s in self.steps_])
        return self

    def _step(self, values: np.ndarray, channel: int, change: int) -> np.ndarray:
        """Per cycle, the level before a change minus the level it settles at, channel's unit."""
        a, b = self.settle
        start = change - self.before
        before = values[:, channel, start - 2 : start].mean(axis=1)
        return np.asarray(before - values[:, channel, change + a : change + b].mean(axis=1))

    def _clear(self, step: np.ndarray) -> bool:
        median = float(np.median(step))
        spread = float(np.median(np.abs(step - median)))
        return bool(median != 0 and abs(median) > self.clear_step * spread)

    def transform(self, values: np.ndarray) -> np.ndarray:
        """Features, shape (n_cycles, n_chosen_channels * n_changes * (before + after) + n_steps * (before +
        after)): the channel's unit, then (``normalised``) the shares of each clear step, dimensionless."""
        if not hasattr(self, "changes_"):
            raise NotFittedError("LoadChangeTransients must be fitted before transform. Call fit(values) first.")
        a, b = self.settle
        chosen = values[:, self.channels_, :]
        parts = []
        for s in self.changes_:
            settled = chosen[:, :, s + a : s + b].mean(axis=2, keepdims=True)
            parts.append(chosen[:, :, s - self.before : s + self.after] - settled)
        plain = np.concatenate(parts, axis=2).reshape(values.shape[0], -1)
        shares = []
        for (c, s), typical in zip(self.steps_, self.typical_steps_, strict=True):
            settled = values[:, c, s + a : s + b].mean(axis=1, keepdims=True)
            step = typical * np.clip(self._step(values, c, s) / typical, 0.5, 2.0)
            shares.append((values[:, c, s - self.before : s + self.after] - settled) / step[:, None])
        return np.concatenate([plain, *shares], axis=1) if shares else plain

    def to_state(self) -> dict[str, Any]:
        """Parameters and fitted arrays (:mod:`hydrowatch.cycles.state`)."""
        if not hasattr(self, "changes_"):
            raise NotFittedError("LoadChangeTransients must be fitted before to_state. Call fit(values) first.")
        return {"reference": self.reference, "threshold": self.threshold, "before": self.before, "after": self.after,
                "settle": list(self.settle), "channels": None if self.channels is None else list(self.channels),
                "normalised": self.normalised, "clear_step": self.clear_step,
                "channels_": self.channels_, "changes_": self.changes_, "steps_": self.steps_,
                "typical_steps_": self.typical_steps_}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> LoadChangeTransients:
        """The inverse of :meth:`to_state`."""
        a, b = state["settle"]
        out = cls(reference=state["reference"], threshold=state["threshold"], before=state["before"],
                  after=state["after"], settle=(a, b), channels=state["channels"],
                  normalised=state.get("normalised", False), clear_step=state.get("clear_step", 10.0))
        out.channels_, out.changes_ = state["channels_"], state["changes_"]
        # a model saved before 2026-11-26 has no shares
        out.steps_ = state.get("steps_", np.zeros((0, 2), dtype=int))
        out.typical_steps_ = state.get("typical_steps_", np.zeros(0))
        return out


class NuisanceProjection:
    """Standardise features and project out the directions other components' conditions move them.

    Fit: within each class of the judged component, the mean of the standardised features of each
    level of each nuisance label (groups of at least ``min_group`` cycles) minus the class mean;
    the ``directions`` leading right singular vectors of these differences span the nuisance
    subspace. Transform: standardise, subtract the projection on that subspace.

    Parameters
    ----------
    directions : int, default 3
        Dimension of the nuisance subspace removed (0 keeps only the standardisation).
    min_group : int, default 5
        Fewest cycles a (class, nuisance level) group needs to count.
    """

    def __init__(self, *, directions: int = 3, min_group: int = 5) -> None:
        self.directions = directions
        self.min_group = min_group

    def fit(self, features: np.ndarray, labels: np.ndarray, nuisance: np.ndarray) -> NuisanceProjection:
        """Learn the subspace from training cycles.

        Parameters
        ----------
        features : ndarray, shape (n_cycles, n_features)
        labels : ndarray, shape (n_cycles,)
            Class of the judged component.
        nuisance : ndarray, shape (n_cycles, n_nuisances)
            Conditions of the other components (one column each).
        """
        if self.directions < 0 or self.min_group < 1:
            raise ParameterError(
                f"directions must be >= 0 and min_group >= 1. Got {self.directions}, {self.min_group}."
            )
        nuisance = nuisance.reshape(len(nuisance), -1)
        self.mean_ = features.mean(axis=0)
        self.scale_ = np.where(features.std(axis=0) > 0, features.std(axis=0), 1.0)
        z = (features - self.mean_) / self.scale_
        shifts = []
        for value in np.unique(labels):
            members = labels == value
            centre = z[members].mean(axis=0)
            for column in nuisance.T:
                for level in np.unique(column[members]):
                    group = members & (column == level)
                    if group.sum() >= self.min_group:
                        shifts.append(z[group].mean(axis=0) - centre)
        if self.directions and not shifts:
            raise ParameterError(
                f"every (class, nuisance level) group has fewer than min_group={self.min_group} "
                "cycles. Lower min_group or give more cycles."
            )
        _, _, vt = np.linalg.svd(np.asarray(shifts).reshape(-1, z.shape[1]), full_matrices=False)
        self.basis_ = vt[: self.directions]
        return self

    def transform(self, features: np.ndarray) -> np.ndarray:
        """Standardised features without their nuisance components, shape (n_cycles, n_features)."""
        if not hasattr(self, "basis_"):
            raise NotFittedError("NuisanceProjection must be fitted before transform. Call fit first.")
        z = (features - self.mean_) / self.scale_
        return z - (z @ self.basis_.T) @ self.basis_

    def to_state(self) -> dict[str, Any]:
        """Parameters and fitted arrays (:mod:`hydrowatch.cycles.state`)."""
        if not hasattr(self, "basis_"):
            raise NotFittedError("NuisanceProjection must be fitted before to_state. Call fit first.")
        return {"directions": self.directions, "min_group": self.min_group, "mean_": self.mean_,
                "scale_": self.scale_, "basis_": self.basis_}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> NuisanceProjection:
        """The inverse of :meth:`to_state`."""
        out = cls(directions=state["directions"], min_group=state["min_group"])
        out.mean_, out.scale_, out.basis_ = state["mean_"], state["scale_"], state["basis_"]
        return out
