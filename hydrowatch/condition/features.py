"""Command-invariant window features: how well each health state's physics explains a window.

The study's features (relative entropies of reference-model prediction errors, Eqs. 5.1-5.3)
measure the command as much as the health when the command differs from the identification
experiment. These features instead ask the component relations of the nominal model
(:mod:`hydrowatch.condition.parity`): per window, each fault's parameter is estimated
(:mod:`hydrowatch.condition.estimates`); per health state ``k`` and relation ``r`` the feature is

    F[r, k] = MSE_r(parameters held inside state k's box) / MSE_r(parameters free)

where state k's box lets its own fault's severity move inside its level's band (warning 12–18 %,
alert 26–34 % speed drop, scaled to the level fitted on the state's own windows) and keeps every
other fault within ``tolerance`` × its warning severity of nominal, and the denominator is the
relation's best fit with its parameter free (a generalised likelihood ratio: the sensor noise
and whatever the command does to the residual level cancel). A window of state ``k`` scores
about 1 on every relation of ``k`` whatever the command; other states score more where the
command makes them differ, and nothing can score less than 1. The layout is that of
:class:`hydrowatch.health.features.RelativeEntropyFeatures`, relation-major
(``[load: states…, motor: states…, valve: states…]``), so the health classifier and the
open-set rule take it unchanged.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.condition import estimates as E
from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.windows import check_window, sliding_windows, window_starts
from hydrowatch.log import event, get_logger
from hydrowatch.plant.faults import FAULTS, LEVEL_BANDS, level_severity, parse_state, severity_for_speed_drop
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS, Recording

_log = get_logger(__name__)
KINDS = ("scores", "severities")
BAND_MARGIN = 0.05
"""Relative widening of each severity band (the band edges are physics, the level is fitted)."""


def windows_from_recording(rec: Recording, window: int = 1000, hop: int = 1000) -> np.ndarray:
    """Raw windows of a recording, shape (n_windows, window, 4).

    Channels: voltage [V], flow [L/min], speed [rad/s], torque [N·m]; window k covers samples
    ``[k·hop, k·hop + window)``.
    """
    check_window(window, hop)
    return np.stack([sliding_windows(rec[c], window, hop) for c in E.CHANNELS], axis=-1)


class ConditionFeatures:
    """Per-window, per-state parity scores (or raw parity severities) of raw signal windows.

    Parameters
    ----------
    window : int, default 1000
        Samples per window (5 s at 200 Hz).
    hop : int, default 1000
        Samples between window starts.
    sensors : sequence of str, default ("flow", "speed", "torque")
        Sensors the machine has; missing ones are filled from the nominal relations (and the
        relations used to fill them drop out).
    nominal : PlantParameters or mapping, optional
        Nominal parameters of the healthy machine (default: plant-model.md's table).
    kind : {"scores", "severities"}, default "scores"
        ``"scores"``: the per-state relation scores (module docstring). ``"severities"``: the
        unconstrained parity estimates, 6 severities and log10 residual ratios of the 2 + 4 fits.
    tolerance : float, default 0.25
        How far (× its warning severity) a fault that is not a state's own may be from nominal.

    Attributes
    ----------
    states_ : tuple of str
    relations_ : tuple of str
        Relations the sensors can test.
    levels_ : dict of str to float
        Fitted severity of each fault state's own fault (median over its windows).
    boxes_ : dict of str to dict of str to (float, float)
        Each state's severity box.
    floors_ : dict of str to float
        Residual floor of each relation (load: (N·m)², motor, valve: (L/min)²).
    feature_names_ : list of str
    """

    def __init__(self, *, window: int = 1000, hop: int = 1000, sensors: Sequence[str] = SENSORS,
                 nominal: PlantParameters | Mapping[str, float] | None = None, kind: str = "scores",
                 tolerance: float = 0.25) -> None:
        self.window = window
        self.hop = hop
        self.sensors = sensors
        self.nominal = nominal
        self.kind = kind
        self.tolerance = tolerance

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters (``nominal`` as a plain dict or None, JSON-able)."""
        nominal = self.nominal.to_dict() if isinstance(self.nominal, PlantParameters) else self.nominal
        return {"window": self.window, "hop": self.hop, "sensors": list(self.sensors),
                "nominal": None if nominal is None else dict(nominal), "kind": self.kind, "tolerance": self.tolerance}

    def _parameters(self) -> PlantParameters:
        check_window(self.window, self.hop)
        unknown = sorted(set(self.sensors) - set(SENSORS))
        if unknown or not self.sensors:
            raise ParameterError(f"sensors must be a non-empty subset of {list(SENSORS)}. Got {list(self.sensors)}.")
        if self.kind not in KINDS:
            raise ParameterError(f"kind must be one of {KINDS}. Got {self.kind!r}.")
        if not 0.0 < self.tolerance < 1.0:
            raise ParameterError(f"tolerance must be in (0, 1). Got {self.tolerance!r}; 0.25 is the default.")
        if isinstance(self.nominal, PlantParameters):
            return self.nominal
        return PlantParameters.from_dict(dict(self.nominal)) if self.nominal is not None else PlantParameters()

    # -- fitting ------------------------------------------------------------------------------------
    def fit(self, windows_by_state: Mapping[str, np.ndarray]) -> ConditionFeatures:
        """Fit each state's severity level and box and the relations' residual floors; returns self.

        Parameters
        ----------
        windows_by_state : mapping of state to ndarray, shape (n_k, window, 4)
            Raw windows of each health state's identification recording (``healthy`` required;
            fault states named ``<fault>_warning`` / ``<fault>_alert``).
        """
        p = self._parameters()
        if "healthy" not in windows_by_state:
            raise DataError(f"windows_by_state must include 'healthy'. Got {sorted(windows_by_state)}.")
        self.nominal_ = p
        self.states_ = tuple(windows_by_state)
        fitted: dict[str, tuple[E.WindowSignals, E.ParityEstimates]] = {}
        for state, windows in windows_by_state.items():
            parse_state(state)
            w = E.check_windows(windows, self.window)
            ok = np.array([r is None for r in self.window_reasons(w)], dtype=bool)
            if ok.sum() < 2:
                raise DataError(f"state '{state}' must have at least 2 valid windows. Got {int(ok.sum())}.")
            sig = E.window_signals(w[ok], self.sensors, p)
            fitted[state] = (sig, E.parity_estimates(sig, p))
        self.relations_ = fitted["healthy"][0].relations
        self.levels_ = {}
        for state in self.states_:
            fault, _ = parse_state(state)
            if fault is not None:
                self.levels_[state] = float(np.median(fitted[state][1].severity[fault]))
        self.boxes_ = {state: self._box(state, p) for state in self.states_}
        sig, est = fitted["healthy"]
        healthy = E.relation_mse(sig, est, p, self.boxes_["healthy"])
        self.floors_ = {r: float(np.median(healthy[r])) for r in self.relations_}
        self.feature_names_ = self._names()
        event(_log, "condition features fitted", states=len(self.states_), relations=",".join(self.relations_),
              kind=self.kind)
        return self

    def _box(self, state: str, p: PlantParameters) -> dict[str, tuple[float, float]]:
        box = {}
        for other in FAULTS:
            tol = self.tolerance * level_severity(other, "warning", p)
            box[other] = (-tol, tol)
        own, level = parse_state(state)
        if own is not None and level is not None:
            named = level_severity(own, level, p)
            lo, hi = (severity_for_speed_drop(own, d, p) / named for d in LEVEL_BANDS[level])
            s = self.levels_[state]
            box[own] = (s * lo * (1.0 - BAND_MARGIN), s * hi * (1.0 + BAND_MARGIN))
        return box

    def _names(self) -> list[str]:
        if self.kind == "scores":
            return [f"{r}|{k}" for r in self.relations_ for k in self.states_]
        fits = [r for r in ("load", "motor") if r in self.relations_] + ["pump_leak", "relief_spring", "valve_coil",
                                                                         "valve_leak"]
        return [f"severity|{f}" for f in FAULTS] + [f"log_residual|{f}" for f in fits]

    def _check_fitted(self) -> None:
        if not hasattr(self, "floors_"):
            raise NotFittedError("ConditionFeatures must be fitted before use. Call fit(windows_by_state) first.")

    # -- transforming -----------------------------------------------------------------------------
    def transform(self, windows: np.ndarray) -> np.ndarray:
        """Features of raw windows (n_windows, window, 4) → (n_windows, n_features); NaN rows are invalid windows."""
        self._check_fitted()
        w = E.check_windows(windows, self.window)
        out = np.full((w.shape[0], len(self.feature_names_)), np.nan)
        ok = np.array([r is None for r in self.window_reasons(w)], dtype=bool)
        if not ok.any():
            return out
        p = self.nominal_
        sig = E.window_signals(w[ok], self.sensors, p)
        est = E.parity_estimates(sig, p)
        if self.kind == "severities":
            fits = [r for r in ("load", "motor") if r in self.relations_] + list(E.parity.VALVE_HYPOTHESES)
            floor = {f: self.floors_["valve" if f in E.parity.VALVE_HYPOTHESES else f] for f in fits}
            columns = [est.severity[f] for f in FAULTS] + [np.log10(np.maximum(est.mse[f], 1e-300) / floor[f])
                                                            for f in fits]
            out[ok] = np.stack(columns, axis=1)
            return out
        cache: dict[tuple[str, float, float], np.ndarray] = {}
        free = {"load": est.mse["load"], "motor": est.mse["motor"],
                "valve": np.min([est.mse[f] for f in E.parity.VALVE_HYPOTHESES], axis=0)}
        scores = np.empty((int(ok.sum()), len(self.relations_), len(self.states_)))
        for k, state in enumerate(self.states_):
            mse = E.relation_mse(sig, est, p, self.boxes_[state], cache)
            for i, r in enumerate(self.relations_):
                scores[:, i, k] = mse[r] / np.maximum(free[r], 1e-300)
        out[ok] = scores.reshape(scores.shape[0], -1)
        return out

    def severities(self, windows: np.ndarray) -> dict[str, np.ndarray]:
        """Unconstrained severity estimates of every fault per window, ``{fault: (n_windows,)}`` (NaN where invalid)."""
        self._check_fitted()
        w = E.check_windows(windows, self.window)
        ok = np.array([r is None for r in self.window_reasons(w)], dtype=bool)
        out = {f: np.full(w.shape[0], np.nan) for f in FAULTS}
        if ok.any():
            est = E.parity_estimates(E.window_signals(w[ok], self.sensors, self.nominal_), self.nominal_)
            for f in FAULTS:
                out[f][ok] = est.severity[f]
        return out

    def window_reasons(self, windows: np.ndarray) -> list[str | None]:
        """Why each raw window (n_windows, window, 4) cannot be judged, or None.

        Invalid: NaN/inf in the command or a used sensor (a gap, a dropped sensor), or a used
        sensor constant over the window (stuck). A constant command is fine (a hold).
        """
        w = E.check_windows(windows, self.window)
        used = [0] + [1 + SENSORS.index(s) for s in self.sensors]
        reasons: list[str | None] = []
        for row in w:
            why = None
            for c in used:
                bad = int((~np.isfinite(row[:, c])).sum())
                if bad:
                    why = f"{E.CHANNELS[c]}: {bad} NaN/inf samples in the window"
                    break
                if c > 0 and np.ptp(row[:, c]) == 0.0:
                    why = f"{E.CHANNELS[c]}: constant over the window (stuck sensor?)"
                    break
            reasons.append(why)
        return reasons

    def window_starts(self, n_samples: int) -> np.ndarray:
        """First sample of each window of a record of ``n_samples`` samples."""
        return window_starts(n_samples, self.window, self.hop)

    # -- persistence --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-able form: parameters and fitted state."""
        self._check_fitted()
        return {"params": self.get_params(), "nominal_parameters": self.nominal_.to_dict(),
                "states": list(self.states_), "relations": list(self.relations_), "levels": self.levels_,
                "boxes": {k: {f: list(b) for f, b in box.items()} for k, box in self.boxes_.items()},
                "floors": self.floors_}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ConditionFeatures:
        """Inverse of :meth:`to_dict`."""
        try:
            model = cls(**{**data["params"], "sensors": tuple(data["params"]["sensors"])})
            model._parameters()
            model.nominal_ = PlantParameters.from_dict(data["nominal_parameters"])
            model.states_ = tuple(data["states"])
            model.relations_ = tuple(data["relations"])
            model.levels_ = {k: float(v) for k, v in data["levels"].items()}
            model.boxes_ = {k: {f: (float(b[0]), float(b[1])) for f, b in box.items()}
                            for k, box in data["boxes"].items()}
            model.floors_ = {k: float(v) for k, v in data["floors"].items()}
        except (KeyError, TypeError, IndexError) as exc:
            raise DataError(f"condition features must have params, states, relations, levels, boxes and floors. "
                            f"Missing/bad: {exc}.") from None
        model.feature_names_ = model._names()
        return model

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_dict` as JSON to ``path``."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> ConditionFeatures:
        """Read a file written by :meth:`save`."""
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"condition features file must be readable JSON. Got: {exc}.", str(path)) from None
        return cls.from_dict(data)
