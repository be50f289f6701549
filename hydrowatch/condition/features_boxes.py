"""The health states' severity boxes of :class:`~hydrowatch.condition.features.ConditionFeatures`, as the windows
judge them.

A state's band box lets its own fault's severity move inside its level's band and keeps every other fault near
nominal; its level box is the narrow point hypothesis (``features.py``'s module docstring). Windows without the oil
temperature widen the leak ranges by the oil's range (:mod:`hydrowatch.condition.oil`); a load state on a unit whose
commissioning left the relief open follows each window's relief (:mod:`hydrowatch.condition.relief`). Split from
``features.py`` (one module, one job): these methods are mixed into ``ConditionFeatures``.
"""

from __future__ import annotations

from collections.abc import Mapping

from hydrowatch.condition import estimates as E
from hydrowatch.condition import ratios as R
from hydrowatch.condition.oil import leakage_range, motor_oil_box, oil_box
from hydrowatch.condition.relief import LoadScale, free_relief, scaled_load_box, window_factors
from hydrowatch.plant.faults import parse_state
from hydrowatch.plant.parameters import PlantParameters

BAND_MARGIN = 0.05
"""Relative widening of each severity band (the band edges are physics, the level is fitted)."""
RELIEF_LIMITS = E.parity.SEVERITY_LIMITS["relief_spring"]
"""The relief fit's search range (:func:`hydrowatch.condition.relief.determined`)."""


class StateBoxes:
    """The box methods of :class:`~hydrowatch.condition.features.ConditionFeatures` (a mixin)."""

    levels_: dict[str, float]
    tolerance: float
    level_width: float
    relief_spread_: float
    nominal_: PlantParameters
    oil_range: float
    viscosity_coefficient: float
    window: int
    boxes_: dict[str, dict[str, tuple[float, float]]]
    level_boxes_: dict[str, dict[str, tuple[float, float]]]
    _scale: LoadScale | None

    def _box(self, state: str, p: PlantParameters, narrow: bool = False,
             margin: float = 0.0) -> dict[str, tuple[float, float]]:
        """A state's band box (``margin`` widens its own fault's band further), or with ``narrow`` its level box."""
        box = R.state_box(state, self.levels_.get(state, 0.0), p, self.tolerance, self.level_width, narrow,
                          BAND_MARGIN + margin)
        return free_relief(box, self.relief_spread_) if self._follows_relief(state) else box

    def _follows_relief(self, state: str) -> bool:
        """Whether ``state`` is a load state on a unit whose relief commissioning left open (module relief)."""
        return getattr(self, "relief_spread_", 0.0) > 0.0 and parse_state(state)[0] == "load"

    def _load_scale(self) -> LoadScale:
        """The load levels' factor at each relief (:class:`~hydrowatch.condition.relief.LoadScale`), made once."""
        scale = getattr(self, "_scale", None)
        if scale is None:
            scale = self._scale = LoadScale(self.nominal_, self.relief_spread_)
        return scale

    def _box_sets(self, temperature: bool) -> tuple[dict[str, dict[str, tuple[float, float]]], ...]:
        """(band, level) boxes of every state that pooling clips to (``evidence_layout``); for windows without the oil
        temperature widened by the whole ``oil_range`` (per window, :meth:`_box_of` narrows them by the motor's oil)."""
        if temperature or self.oil_range == 0.0:
            return self.boxes_, self.level_boxes_
        factors = leakage_range(self.viscosity_coefficient, self.oil_range)
        return tuple({s: oil_box(b, self.nominal_, factors) for s, b in boxes.items()}
                     for boxes in (self.boxes_, self.level_boxes_))

    def _box_of(self, state: str, box: Mapping[str, tuple[float, float]], known: bool = True) -> R.BoxOf:
        """``box`` as the windows judge it: without the oil temperature its leak ranges widened by the oil's range
        (:mod:`hydrowatch.condition.oil`), per window by what the motor's leakage tells of the oil unless the state
        is a motor leak (:func:`~hydrowatch.condition.oil.motor_factors`); for a state that follows the relief, its
        load range scaled by each window's relief."""
        oil = None if known or self.oil_range == 0.0 else leakage_range(self.viscosity_coefficient, self.oil_range)
        if oil is not None and parse_state(state)[0] == "motor_leak":  # its motor path is the fault: the whole range
            box, oil = oil_box(box, self.nominal_, oil), None
        scale = self._load_scale() if self._follows_relief(state) else None
        if oil is None and scale is None:
            return box
        p, blocks = self.nominal_, (self.window - 1) // E.parity.BLOCK

        def of(est: E.ParityEstimates) -> R.Box:
            out: R.Box = box if oil is None else motor_oil_box(
                box, p, est.severity["motor_leak"],
                E.severity_standard_error(est.mse["motor"], est.curvature["motor_leak"], blocks), oil)
            return out if scale is None else scaled_load_box(out, *window_factors(
                scale, est.severity["relief_spring"], est.curvature["relief_spring"], RELIEF_LIMITS)[:2])
        return of
