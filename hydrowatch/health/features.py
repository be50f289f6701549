"""The classifier's inputs: relative entropy of every window against every base distribution.

Per window and sensor, the prediction errors are summarised by a distribution ``Q`` (Gaussian by
moments, or a Gaussian mixture by EM) and compared with the base distribution ``P`` of every
health state by ``D(P || Q)`` (Eq. 5.2/5.3, base first, window second, as in the study). With
the study's 3 sensors and 7 states that is 21 numbers per window (section 6.3), ordered
sensor-major: ``[flow: state 1..7, speed: state 1..7, torque: state 1..7]`` like the rows of
Table 6.1.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.distributions import Mixture, fit_gaussian, fit_mixture
from hydrowatch.health.entropy import gaussian_relative_entropy, mixture_relative_entropy, quadrature_rule
from hydrowatch.health.windows import DEFAULT_WINDOW, check_window, invalid_reasons, sliding_windows, window_starts
from hydrowatch.log import event, get_logger
from hydrowatch.recording import SENSORS

_log = get_logger(__name__)
DISTRIBUTIONS = ("gaussian", "mixture")
LOG_FLOOR = 1e-6
"""Relative entropies are floored at this value (nats) before the log transform."""


def log_features(features: np.ndarray, floor: float = LOG_FLOOR) -> np.ndarray:
    """``log(max(D, floor))`` of relative entropies, elementwise; NaN stays NaN.

    Relative entropies span decades (0.003 to 72 nats in Table 6.1): the log spreads the small
    values a window gets against its own and similar states, where the classifier must decide.
    """
    x = np.asarray(features, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.log(np.maximum(x, floor))


class RelativeEntropyFeatures:
    """Base distributions per health state and sensor, and window relative entropies against them.

    Parameters
    ----------
    distribution : {"gaussian", "mixture"}, default "gaussian"
        ``"gaussian"``: the study's Gaussian base and window distributions, Eq. 5.3 (closed form,
        a few microseconds per window). ``"mixture"``: Gaussian mixtures for both (the study's
        proposed improvement), Eq. 5.2 by quadrature; a window mixture is fitted by EM per window
        (milliseconds per window and sensor).
    n_components : int, default 3
        Components of a base mixture (``distribution="mixture"`` only).
    window_components : int, default 2
        Components of a window mixture (``distribution="mixture"`` only).
    window : int, default 1000
        Samples per window, 5 s at 200 Hz.
    hop : int, default 1000
        Samples between window starts (``window``: no overlap).
    random_state : int, default 0
        Seed of the EM initialisations.

    Attributes
    ----------
    states_ : tuple of str
        Health states, in the order of the features and of the classifier's outputs.
    sensors_ : tuple of str
    bases_ : list of list of Mixture
        ``bases_[i][k]``: base distribution of sensor ``i`` in state ``k``.
    feature_names_ : list of str
        ``"<sensor>|<state>"`` for each of the ``n_sensors * n_states`` features.
    """

    def __init__(
        self,
        *,
        distribution: str = "gaussian",
        n_components: int = 3,
        window_components: int = 2,
        window: int = DEFAULT_WINDOW,
        hop: int = DEFAULT_WINDOW,
        random_state: int = 0,
    ) -> None:
        self.distribution = distribution
        self.n_components = n_components
        self.window_components = window_components
        self.window = window
        self.hop = hop
        self.random_state = random_state

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {k: getattr(self, k) for k in ("distribution", "n_components", "window_components", "window",
                                              "hop", "random_state")}

    def _check_params(self) -> None:
        if self.distribution not in DISTRIBUTIONS:
            raise ParameterError(f"distribution must be one of {DISTRIBUTIONS}. Got {self.distribution!r}.")
        check_window(self.window, self.hop)
        if self.distribution == "mixture" and not 1 <= self.window_components <= self.window // 20:
            raise ParameterError(
                f"window_components must be between 1 and window/20 = {self.window // 20}. "
                f"Got {self.window_components}; use fewer components or longer windows."
            )

    def _fit_one(self, errors: np.ndarray, n_components: int) -> Mixture:
        if self.distribution == "gaussian":
            return fit_gaussian(errors)
        return fit_mixture(errors, n_components, random_state=self.random_state)

    def fit(
        self, errors_by_state: Mapping[str, np.ndarray], sensors: Sequence[str] = SENSORS
    ) -> RelativeEntropyFeatures:
        """Fit the base distribution of every state and sensor; returns self.

        Parameters
        ----------
        errors_by_state : mapping of str to ndarray, shape (n_k, n_sensors)
            Per health state, the reference models' prediction errors (Eq. 5.1) on that state's
            base part of the data plan (40,000 samples in the study), one column per sensor.
        sensors : sequence of str, default ("flow", "speed", "torque")
            Sensor of each column.
        """
        self._check_params()
        if len(errors_by_state) < 1:
            raise DataError("errors_by_state must hold at least one health state. Got none.")
        sensors = tuple(sensors)
        bases: list[list[Mixture]] = [[] for _ in sensors]
        for state, errors in errors_by_state.items():
            e = _as_columns(errors, len(sensors), f"prediction errors of state '{state}'")
            for i, sensor in enumerate(sensors):
                try:
                    bases[i].append(self._fit_one(e[:, i], self.n_components))
                except DataError as exc:
                    raise DataError(f"state '{state}', sensor '{sensor}': {exc}") from None
        self.states_ = tuple(errors_by_state)
        self.sensors_ = sensors
        self.bases_ = bases
        self._prepare()
        event(_log, "base distributions fitted", states=len(self.states_), sensors=len(sensors),
              distribution=self.distribution)
        return self

    def _prepare(self) -> None:
        self.feature_names_ = [f"{s}|{k}" for s in self.sensors_ for k in self.states_]
        if self.distribution == "gaussian":
            self._base_means = [np.array([b.means[0] for b in row]) for row in self.bases_]
            self._base_stds = [np.array([b.stds[0] for b in row]) for row in self.bases_]
        else:
            self._rules = [[quadrature_rule(b) for b in row] for row in self.bases_]

    def _check_fitted(self) -> None:
        if not hasattr(self, "bases_"):
            raise NotFittedError("RelativeEntropyFeatures must be fitted before use. Call fit(errors_by_state) first.")

    def sensor_index(self, sensor: str | int) -> int:
        """Column of ``sensor`` (a name or an index)."""
        self._check_fitted()
        if isinstance(sensor, str):
            if sensor not in self.sensors_:
                raise ParameterError(f"sensor must be one of {self.sensors_}. Got {sensor!r}.")
            return self.sensors_.index(sensor)
        if not 0 <= int(sensor) < len(self.sensors_):
            raise ParameterError(f"sensor index must be in [0, {len(self.sensors_)}). Got {sensor}.")
        return int(sensor)

    def sensor_entropies(self, windows: np.ndarray, sensor: str | int) -> np.ndarray:
        """``D(base || window)`` of one sensor's windows against every state, nats.

        Parameters
        ----------
        windows : ndarray, shape (n_windows, window)
            Prediction errors of the sensor, one window per row.
        sensor : str or int

        Returns
        -------
        ndarray, shape (n_windows, n_states)
            NaN rows for invalid windows (see :func:`~hydrowatch.health.windows.invalid_reasons`).
        """
        i = self.sensor_index(sensor)
        w = np.asarray(windows, dtype=np.float64)
        finite = np.asarray(np.isfinite(w).all(axis=1), dtype=bool)
        ok = finite & (np.ptp(np.where(finite[:, None], w, 0.0), axis=1) > 0.0)  # as invalid_reasons
        if self.distribution == "gaussian":
            with np.errstate(invalid="ignore"):
                mean, std = w.mean(axis=1), w.std(axis=1)
            out = gaussian_relative_entropy(
                self._base_means[i][None, :], self._base_stds[i][None, :], mean[:, None], std[:, None]
            )
            out[~ok] = np.nan
            return out
        out = np.full((w.shape[0], len(self.states_)), np.nan)
        if not ok.any():
            return out
        good = w[ok]
        fits = [self._fit_one(row, self.window_components) for row in good]
        stacked = Mixture(*(np.stack([getattr(f, a) for f in fits]) for a in ("weights", "means", "stds")))
        for k, base in enumerate(self.bases_[i]):
            out[ok, k] = mixture_relative_entropy(base, stacked, rule=self._rules[i][k])
        return out

    def window_entropies(self, errors: np.ndarray) -> np.ndarray:
        """Relative entropies of every window, shape (n_windows, n_sensors, n_states), nats.

        Parameters
        ----------
        errors : ndarray, shape (n, n_sensors)
            Prediction errors of one machine, one column per sensor (order of ``sensors_``).
        """
        self._check_fitted()
        e = _as_columns(errors, len(self.sensors_), "prediction errors")
        per_sensor = [self.sensor_entropies(sliding_windows(e[:, i], self.window, self.hop), i)
                      for i in range(len(self.sensors_))]
        return np.stack(per_sensor, axis=1)

    def transform(self, errors: np.ndarray) -> np.ndarray:
        """Feature vectors, shape (n_windows, n_sensors * n_states), sensor-major; NaN rows are invalid windows."""
        d = self.window_entropies(errors)
        return d.reshape(d.shape[0], -1)

    def window_reasons(self, errors: np.ndarray) -> list[str | None]:
        """Why each window of ``errors`` (n, n_sensors) is invalid (``"<sensor>: <why>"``), or None."""
        self._check_fitted()
        e = _as_columns(errors, len(self.sensors_), "prediction errors")
        per_sensor = [invalid_reasons(sliding_windows(e[:, i], self.window, self.hop)) for i in range(e.shape[1])]
        return [next((f"{s}: {r}" for s, r in zip(self.sensors_, rs) if r), None) for rs in zip(*per_sensor)]

    def window_starts(self, n_samples: int) -> np.ndarray:
        """First sample of each window of a record of ``n_samples`` samples."""
        return window_starts(n_samples, self.window, self.hop)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form: parameters, states, sensors and base distributions."""
        self._check_fitted()
        return {"params": self.get_params(), "states": list(self.states_), "sensors": list(self.sensors_),
                "bases": [[b.to_dict() for b in row] for row in self.bases_]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RelativeEntropyFeatures:
        """Inverse of :meth:`to_dict`."""
        try:
            model = cls(**data["params"])
            model._check_params()
            model.states_ = tuple(data["states"])
            model.sensors_ = tuple(data["sensors"])
            model.bases_ = [[Mixture.from_dict(b) for b in row] for row in data["bases"]]
        except (KeyError, TypeError) as exc:
            raise DataError(
                f"base distributions must have params, states, sensors and bases. Missing/bad: {exc}."
            ) from None
        if [len(r) for r in model.bases_] != [len(model.states_)] * len(model.sensors_):
            raise DataError("base distributions must hold one entry per sensor and state. Got a ragged table.")
        model._prepare()
        return model

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_dict` as JSON to ``path``."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> RelativeEntropyFeatures:
        """Read a file written by :meth:`save`."""
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"base distributions file must be readable JSON. Got: {exc}.", str(path)) from None
        return cls.from_dict(data)


def _as_columns(errors: np.ndarray, n_sensors: int, what: str) -> np.ndarray:
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim == 1 and n_sensors == 1:
        e = e[:, np.newaxis]
    if e.ndim != 2 or e.shape[1] != n_sensors:
        raise DataError(f"{what} must have shape (n, {n_sensors}), one column per sensor. Got {e.shape}.")
    return e
