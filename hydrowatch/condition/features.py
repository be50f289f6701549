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

:meth:`ConditionFeatures.transform_with_levels` adds the same ratios for each state's narrow
**level box** (own severity within ``level_width`` of the fitted level, the others within
``level_width`` × their warning severity of nominal: the state's point hypothesis), which the
decision weighs by ``level_weight`` (a soft prior that a machine sits near its state's trained
severity). In a hold the band boxes of valve_coil, valve_leak, pump_leak and relief_spring all
explain the window (they agree on speed at 2 V and differ by 1–2 % elsewhere, inside a band); at
their trained levels they differ, which breaks the tie wherever the hold is away from 2 V. The
open-set rule uses the band ratios only, so a severity anywhere in its band is still a known state.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.condition import estimates as E
from hydrowatch.condition import layout as L
from hydrowatch.condition import ratios as R
from hydrowatch.condition.features_evidence import EvidenceRows
from hydrowatch.condition.features_store import features_from_dict, features_to_dict
from hydrowatch.condition.oil import OIL_RANGE, oil_parts
from hydrowatch.condition.standstill import without_load_relation
from hydrowatch.condition.unit import UnitFit, identify_unit, left_to_prior
from hydrowatch.condition.unit_checks import capacity_determined
from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.windows import check_window, window_starts
from hydrowatch.log import event, get_logger
from hydrowatch.plant.faults import fault_parameters, level_severity, parse_state
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS

_log = get_logger(__name__)


class ConditionFeatures(EvidenceRows):  # and StateBoxes, through EvidenceRows
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
    tolerance : float, default 0.25
        How far (× its warning severity) a fault that is not a state's own may be from nominal.
    level_weight : float, default 1.0
        Weight of the level-box ratios in the decision (0: band boxes only); see
        :class:`hydrowatch.condition.model.ParityRule`.
    level_width : float, default 0.01
        Half-width of the level box: relative to the fitted level for a state's own fault, × the
        warning severity for the others.
    viscosity_coefficient : float, default 0.04
        k, 1/K, of the oil: viscosity ∝ exp(−k·(T − 40 °C)). Used with windows that carry the
        temperature channel to refer leakage to 40 °C (take it from the oil's data sheet; 0.04 is
        a mineral ISO VG 46 oil near 40 °C and the plant simulator's default).
    oil_range : float, default :data:`~hydrowatch.condition.oil.OIL_RANGE` (5 K)
        Half-range of the oil temperature around 40 °C, K, that a window *without* the temperature
        channel (4 channels, or a temperature channel all NaN) may have: its leak boxes are widened
        by that viscosity range (:mod:`hydrowatch.condition.oil`). 0 reads such windows as 40 °C oil.
    identify : bool, default True
        Identify the unit's own nominal parameters from the ``healthy`` windows before anything
        else (:func:`hydrowatch.condition.unit.identify_unit`, starting from ``nominal``): every
        box and level is then relative to this unit, not to the design values. False keeps
        ``nominal`` as given (right only for a unit that really has those parameters).

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
    nominal_ : PlantParameters
        The unit's own nominal parameters (identified, or ``nominal`` as given).
    unit_ : dict
        :meth:`hydrowatch.condition.unit.UnitFit.summary` of the identification ({} without it).
    relief_spread_ : float
        Log-scale half-width of the relief a commissioning recording left undetermined (0: determined, and
        for every trained model); the load states then follow each window's relief (:mod:`.relief`).
    capacity_known_ : bool
        Whether the pump's capacity Dp·ωp is determined (False: a commissioning recording never drove the pump to its
        limit; pump_leak's index then waits for the machine's history, :mod:`hydrowatch.condition.capacity`).
    pump_at_limit_ : float or None
        Share of the identification (or commissioning) recording's samples with the pump at its limit
        (:func:`~hydrowatch.condition.unit_checks.pump_at_limit_share`; None: not identified, or not known). From
        :data:`~hydrowatch.condition.unit_checks.RELIEF_SHUT_SHARE` the relief's gain is barely seen and the relief
        spring's early wear is not told from the coil's (:func:`~hydrowatch.condition.attribution.contenders`).
    feature_names_ : list of str
    """

    def __init__(self, *, window: int = 1000, hop: int = 1000, sensors: Sequence[str] = SENSORS,
                 nominal: PlantParameters | Mapping[str, float] | None = None,
                 tolerance: float = 0.25, level_weight: float = 1.0, level_width: float = 0.01,
                 viscosity_coefficient: float = 0.04, identify: bool = True, oil_range: float = OIL_RANGE) -> None:
        self.window = window
        self.hop = hop
        self.sensors = sensors
        self.nominal = nominal
        self.tolerance = tolerance
        self.level_weight = level_weight
        self.level_width = level_width
        self.viscosity_coefficient = viscosity_coefficient
        self.identify = identify
        self.oil_range = oil_range

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters (``nominal`` as a plain dict or None, JSON-able)."""
        nominal = self.nominal.to_dict() if isinstance(self.nominal, PlantParameters) else self.nominal
        return {"window": self.window, "hop": self.hop, "sensors": list(self.sensors),
                "nominal": None if nominal is None else dict(nominal), "tolerance": self.tolerance,
                "level_weight": self.level_weight, "level_width": self.level_width,
                "viscosity_coefficient": self.viscosity_coefficient, "identify": self.identify,
                "oil_range": self.oil_range}

    def _parameters(self) -> PlantParameters:
        check_window(self.window, self.hop)
        unknown = sorted(set(self.sensors) - set(SENSORS))
        if unknown or not self.sensors:
            raise ParameterError(f"sensors must be a non-empty subset of {list(SENSORS)}. Got {list(self.sensors)}.")
        if not 0.0 < self.tolerance < 1.0:
            raise ParameterError(f"tolerance must be in (0, 1). Got {self.tolerance!r}; 0.25 is the default.")
        if not (self.level_weight >= 0.0 and 0.0 < self.level_width < self.tolerance):
            raise ParameterError(f"level_weight must be >= 0 and level_width in (0, tolerance). Got "
                                 f"{self.level_weight!r}, {self.level_width!r}; the defaults are 1.0 and 0.01.")
        if not 0.0 <= self.viscosity_coefficient <= 0.2:
            raise ParameterError(f"viscosity_coefficient must be in [0, 0.2] 1/K. Got {self.viscosity_coefficient!r}; "
                                 "0.04 suits a mineral oil near 40 °C.")
        if not 0.0 <= self.oil_range <= 30.0:
            raise ParameterError(f"oil_range must be in [0, 30] K. Got {self.oil_range!r}; {OIL_RANGE} is the default.")
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
        self.unit_: dict[str, Any] = {}
        self.relief_spread_, self.brake_open_, self.capacity_known_ = 0.0, False, True
        self.pump_at_limit_: float | None = None
        if self.identify:
            healthy = L.check_windows(windows_by_state["healthy"], self.window)
            unit = identify_unit(healthy, p, self.sensors, self.viscosity_coefficient)
            p, self.unit_ = unit.parameters, unit.summary()
            self.brake_open_ = "omega_s" in left_to_prior(unit)
            self.capacity_known_, self.pump_at_limit_ = capacity_determined(healthy, p, self.sensors,
                                                                            self.viscosity_coefficient)
        self.nominal_ = p
        # healthy first: argmax keeps the first of equal scores, and in a window no fault shows in,
        # the faults that only show under load tie with healthy (ParityRule)
        self.states_ = ("healthy", *(s for s in windows_by_state if s != "healthy"))
        filled = E.fill_faults(self.sensors)
        # A fault whose parameter fills a missing sensor sits at its named level (its own relation is gone).
        self.levels_ = {state: level_severity(f, lvl, p) for state in self.states_
                        for f, lvl in [parse_state(state)] if f in filled and lvl is not None}
        fitted: dict[str, tuple[E.WindowSignals, E.ParityEstimates]] = {}
        for state, windows in windows_by_state.items():
            w = L.check_windows(windows, self.window)
            ok = np.array([r is None for r in self.window_reasons(w)], dtype=bool)
            if ok.sum() < 2:
                raise DataError(f"state '{state}' must have at least 2 valid windows. Got {int(ok.sum())}.")
            sig = E.window_signals(w[ok], self.sensors, p, self.viscosity_coefficient, self._fill(state))
            fitted[state] = (sig, E.parity_estimates(sig, p))
        self.relations_ = fitted["healthy"][0].relations
        for state in self.states_:
            fault, _ = parse_state(state)
            if fault is not None and state not in self.levels_:
                self.levels_[state] = float(np.median(fitted[state][1].severity[fault]))
        self.boxes_ = {state: self._box(state, p) for state in self.states_}
        self.level_boxes_ = {state: self._box(state, p, narrow=True) for state in self.states_}
        self.floors_ = self._floors(*fitted["healthy"])
        self.feature_names_ = self._names()
        event(_log, "condition features fitted", states=len(self.states_), relations=",".join(self.relations_))
        return self

    def _floors(self, sig: E.WindowSignals, est: E.ParityEstimates) -> dict[str, float]:
        """Each relation's residual floor: the median healthy-box MSE of healthy windows."""
        healthy = E.relation_mse(sig, est, self.nominal_, self.boxes_["healthy"])
        return {r: float(np.median(healthy[r])) for r in self.relations_}

    def for_unit(self, unit: UnitFit, healthy: np.ndarray, margin: float = 0.0,
                 relief_spread: float = 0.0) -> ConditionFeatures:
        """These features moved to another unit of the fleet (commissioning, :mod:`~hydrowatch.condition.commission`).

        The unit's nominal parameters replace the trained unit's. Every fault level keeps its
        meaning, a speed drop at 2 V on *this* unit: level × level_severity(unit) /
        level_severity(trained unit) (:func:`~hydrowatch.plant.faults.level_severity`). That is
        an extrapolation to loads the unit's healthy data never reached, so each band box is
        widened by ``margin`` (a fraction of its bounds) on top of the trained one. Residual
        floors are measured on the unit's own ``healthy`` windows (its DAQ's noise). With ``relief_spread`` > 0
        (the recording left the relief undetermined, log scale) the load states follow each window's relief
        (:mod:`hydrowatch.condition.relief`). Returns a new fitted instance; ``self`` is unchanged.
        """
        self._check_fitted()
        out = ConditionFeatures.from_dict(self.to_dict())
        p = out.nominal_ = unit.parameters
        for state, level in self.levels_.items():
            fault, name = parse_state(state)
            if fault is not None and name is not None:
                out.levels_[state] = level * level_severity(fault, name, p) / level_severity(fault, name, self.nominal_)
        out.relief_spread_ = float(relief_spread)
        out.brake_open_ = "omega_s" in left_to_prior(unit)
        out.boxes_ = {s: out._box(s, p, margin=margin) for s in out.states_}
        out.level_boxes_ = {s: out._box(s, p, narrow=True) for s in out.states_}
        w = L.check_windows(healthy, self.window)
        ok = np.array([r is None for r in out.window_reasons(w)], dtype=bool)
        if ok.sum() < 2:
            raise DataError(f"commissioning needs at least 2 valid healthy windows. Got {int(ok.sum())}.")
        sig = E.window_signals(w[ok], self.sensors, p, self.viscosity_coefficient, p)
        out.floors_ = out._floors(sig, E.parity_estimates(sig, p))
        out.unit_ = unit.summary()
        return out

    def _names(self) -> list[str]:
        return [f"{r}|{k}" for r in self.relations_ for k in self.states_]

    def _check_fitted(self) -> None:
        if not hasattr(self, "floors_"):
            raise NotFittedError("ConditionFeatures must be fitted before use. Call fit(windows_by_state) first.")

    # -- transforming -----------------------------------------------------------------------------
    def _fill(self, state: str) -> PlantParameters:
        """Parameters that fill the missing sensors for ``state``: its own fault at its level if the fill uses it."""
        fault, _ = parse_state(state)
        if fault in E.fill_faults(self.sensors):
            return fault_parameters(self.nominal_, fault, self.levels_[state])
        return self.nominal_

    def _by_oil(self, windows: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, bool]]:
        """The windows split by whether they carry the oil temperature: (mask, windows, known) per part present; a
        window without it (4 channels, or the temperature all NaN) goes as 4 channels (boxes: :meth:`_box_of`)."""
        self._check_fitted()
        return oil_parts(L.check_windows(windows, self.window), L.WIDTH)

    def _estimates(self, w: np.ndarray) -> tuple[np.ndarray, list[R.FillGroup]]:
        """Valid-window mask (n,) and the fill groups of the valid windows (nominal fill first; [] if none valid)
        of checked windows ``w`` of one oil part (:meth:`_by_oil`).

        With every sensor present there is one group; otherwise one per distinct fill
        (:func:`hydrowatch.condition.estimates.fill_faults`): at most 5, not one per state.
        """
        ok = np.array([r is None for r in self.window_reasons(w)], dtype=bool)
        if not ok.any():
            return ok, []
        members: dict[str, list[int]] = {"nominal": []}
        for k, state in enumerate(self.states_):
            fill = self._fill(state)
            members.setdefault("nominal" if fill is self.nominal_ else state, []).append(k)
        groups = []
        for key, states in members.items():
            fill = self.nominal_ if key == "nominal" else self._fill(key)
            sig = E.window_signals(w[ok], self.sensors, self.nominal_, self.viscosity_coefficient, fill)
            # Only load and motor states get their own fill; their boxes hold the valve at nominal.
            groups.append(R.FillGroup(tuple(states), sig, E.parity_estimates(sig, self.nominal_, key == "nominal")))
        return ok, groups

    def transform(self, windows: np.ndarray) -> np.ndarray:
        """Features of raw windows (n_windows, window, 4) → (n_windows, n_features); NaN rows are invalid windows."""
        parts = self._by_oil(windows)
        out = np.full((sum(m.sum() for m, _, _ in parts), len(self.feature_names_)), np.nan)
        for mask, w, known in parts:
            ok, groups = self._estimates(w)
            if not groups:
                continue
            rows = np.full((ok.size, out.shape[1]), np.nan)
            rows[ok] = self._ratios(groups, known, sets=1)[0][0]
            out[mask] = rows
        return out

    def transform_with_levels(self, windows: np.ndarray) -> np.ndarray:
        """Band-box scores and level-box scores side by side, (n_windows, 2 · n_features); NaN rows invalid.

        The first half holds the band-box ratios of :meth:`transform`; the second half the same
        ratios with each state's level box (module docstring). ``ParityRule`` decides on both.
        """
        return self.transform_evidence(windows)[:, : 2 * len(self.feature_names_)]

    def _ratios(self, groups: Sequence[R.FillGroup], known: bool, sets: int = 2
                ) -> tuple[list[np.ndarray], dict[str, np.ndarray], list[np.ndarray]]:
        """:func:`hydrowatch.condition.ratios.state_ratios` for the first ``sets`` of the box sets (band, level),
        of windows with the oil temperature (``known``) or without it (:meth:`_box_of`)."""
        boxes = (self.boxes_, self.level_boxes_)[:sets]
        ratios, free, others = R.state_ratios(
            groups, self.nominal_, self.relations_,
            [[self._box_of(state, b[state], known) for state in self.states_] for b in boxes], self._own_faults())
        stalled = self._stalled(groups)  # near standstill with ωs left to its prior the load relation is not judged
        for part in ratios:
            without_load_relation(part, self.feature_names_, stalled)
        return ratios, free, others

    def window_reasons(self, windows: np.ndarray) -> list[str | None]:
        """Why each raw window (n_windows, window, 4) cannot be judged, or None.

        Invalid: NaN/inf in the command, a used sensor or the temperature channel (a gap, a dropped
        sensor), or a used sensor constant over the window (stuck). A constant command or
        temperature is fine (a hold, a warm machine); a temperature all NaN is an unknown oil
        temperature (``oil_range``).
        """
        return L.invalid_reasons(L.check_windows(windows, self.window), self.sensors)

    def window_starts(self, n_samples: int) -> np.ndarray:
        """First sample of each window of a record of ``n_samples`` samples."""
        return window_starts(n_samples, self.window, self.hop)

    # -- persistence (:mod:`hydrowatch.condition.features_store`) ------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-able form: parameters and fitted state."""
        self._check_fitted()
        return features_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ConditionFeatures:
        """Inverse of :meth:`to_dict`."""
        return features_from_dict(cls, data)

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
