"""Base prediction-error distributions: one per health state and sensor (study sections 5.2.3, 6.3).

The study fits each state's prediction errors (Eq. 5.1) with a Gaussian; its conclusion (chapter 7)
proposes a Gaussian mixture because the errors are skewed (Figure 5.3). Both are represented by
:class:`Mixture` (a Gaussian is a one-component mixture), so the relative entropy code in
:mod:`hydrowatch.health.entropy` serves both.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.errors import DataError, NotFittedError, ParameterError

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Mixture:
    """One-dimensional Gaussian mixture(s), possibly a batch of them.

    Parameters
    ----------
    weights, means, stds : ndarray, shape (..., K)
        Component weights (sum to 1 along the last axis), means and standard deviations, in the
        unit of the prediction error (L/min, rad/s or N·m). Leading axes index a batch (windows).
    """

    weights: np.ndarray
    means: np.ndarray
    stds: np.ndarray

    @property
    def n_components(self) -> int:
        """K, components per mixture."""
        return int(self.weights.shape[-1])

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density at ``x``, shape ``batch + x.shape`` (``x`` broadcasts after the batch axes)."""
        x = np.asarray(x, dtype=np.float64)
        extra = (np.newaxis,) * x.ndim
        w = self.weights[(..., *extra, slice(None))]
        mu = self.means[(..., *extra, slice(None))]
        sd = self.stds[(..., *extra, slice(None))]
        z = (x[..., np.newaxis] - mu) / sd
        comp = np.log(w) - 0.5 * z * z - np.log(sd) - 0.5 * _LOG_2PI
        top = comp.max(axis=-1, keepdims=True)
        return np.squeeze(top, -1) + np.log(np.exp(comp - top).sum(axis=-1))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws from a single (unbatched) mixture, shape (n,)."""
        if self.weights.ndim != 1:
            raise ParameterError(f"sample needs a single mixture. Got a batch of shape {self.weights.shape[:-1]}.")
        k = rng.choice(self.n_components, size=n, p=self.weights / self.weights.sum())
        return self.means[k] + self.stds[k] * rng.standard_normal(n)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (single mixture)."""
        return {"weights": self.weights.tolist(), "means": self.means.tolist(), "stds": self.stds.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Mixture:
        """Inverse of :meth:`to_dict`."""
        return cls(*(np.asarray(data[k], dtype=np.float64) for k in ("weights", "means", "stds")))


def _check_errors(errors: np.ndarray, what: str) -> np.ndarray:
    x = np.asarray(errors, dtype=np.float64)
    if x.ndim != 1 or x.shape[0] < 2:
        raise DataError(f"{what} must be a 1-D array of at least 2 prediction errors. Got shape {x.shape}.")
    if not np.all(np.isfinite(x)):
        raise DataError(f"{what} must be finite. Got {int(np.sum(~np.isfinite(x)))} NaN/inf values; drop them first.")
    if np.std(x) == 0.0:
        raise DataError(f"{what} must vary (standard deviation > 0). Got a constant {x[0]!r}; check the sensor.")
    return x


def fit_gaussian(errors: np.ndarray) -> Mixture:
    """Gaussian of the prediction errors (mean, population standard deviation), as a 1-component mixture."""
    x = _check_errors(errors, "prediction errors")
    return Mixture(np.ones(1), np.array([x.mean()]), np.array([x.std()]))


def fit_mixture(errors: np.ndarray, n_components: int = 3, *, random_state: int = 0, max_iter: int = 200) -> Mixture:
    """Gaussian mixture of the prediction errors by EM (scikit-learn's ``GaussianMixture``).

    The errors are standardised before EM (so the variance floor ``reg_covar=1e-6`` is relative to
    the errors' variance, whatever their unit) and the components are returned sorted by mean.
    """
    from sklearn.exceptions import ConvergenceWarning  # here, not at import: scikit-learn takes ~1.3 s to import, and
    from sklearn.mixture import GaussianMixture  # judging (the parity scorer, Mixture's densities) needs none of it

    x = _check_errors(errors, "prediction errors")
    if n_components < 1 or n_components > x.shape[0] // 2:
        raise ParameterError(
            f"n_components must be between 1 and half the samples ({x.shape[0] // 2}). Got {n_components}."
        )
    centre, scale = x.mean(), x.std()
    gm = GaussianMixture(
        n_components=n_components, covariance_type="spherical", max_iter=max_iter, random_state=random_state,
        init_params="k-means++",
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gm.fit(((x - centre) / scale)[:, np.newaxis])
    order = np.argsort(gm.means_[:, 0])
    return Mixture(
        gm.weights_[order].astype(np.float64),
        centre + scale * gm.means_[order, 0],
        scale * np.sqrt(gm.covariances_[order]),
    )


class GaussianBase:
    """Gaussian base prediction-error distribution of one health state and sensor (study Eq. 5.3 inputs).

    Attributes
    ----------
    mean_, std_ : float
        Mean and standard deviation of the errors (sensor unit).
    mixture_ : Mixture
        The same as a one-component mixture.
    """

    def fit(self, errors: np.ndarray) -> GaussianBase:
        """Fit to prediction errors, shape (n,); returns self."""
        self.mixture_ = fit_gaussian(errors)
        self.mean_ = float(self.mixture_.means[0])
        self.std_ = float(self.mixture_.stds[0])
        return self

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density at ``x`` (1/sensor unit)."""
        return _fitted(self).logpdf(x)


class MixtureBase:
    """Gaussian-mixture base prediction-error distribution (the study's proposed improvement, ch. 7).

    Parameters
    ----------
    n_components : int, default 3
        Mixture components.
    random_state : int, default 0
        Seed of EM's initialisation.

    Attributes
    ----------
    weights_, means_, stds_ : ndarray, shape (n_components,)
        Components sorted by mean (sensor unit).
    mixture_ : Mixture
    """

    def __init__(self, *, n_components: int = 3, random_state: int = 0) -> None:
        self.n_components = n_components
        self.random_state = random_state

    def fit(self, errors: np.ndarray) -> MixtureBase:
        """Fit to prediction errors, shape (n,); returns self."""
        self.mixture_ = fit_mixture(errors, self.n_components, random_state=self.random_state)
        self.weights_, self.means_, self.stds_ = self.mixture_.weights, self.mixture_.means, self.mixture_.stds
        return self

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density at ``x`` (1/sensor unit)."""
        return _fitted(self).logpdf(x)


def _fitted(model: GaussianBase | MixtureBase) -> Mixture:
    mixture = getattr(model, "mixture_", None)
    if mixture is None:
        raise NotFittedError(f"{type(model).__name__} must be fitted before use. Call fit(errors) first.")
    return mixture
