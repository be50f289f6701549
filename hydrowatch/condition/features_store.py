"""Saving and loading :class:`~hydrowatch.condition.features.ConditionFeatures` as plain JSON-able dicts.

The dict holds the constructor parameters and the fitted state: the unit's nominal parameters,
states, relations, levels, band and level boxes, residual floors and the unit identification's
summary. Boxes are stored, not recomputed on load: a commissioned unit's boxes were moved to it
(:meth:`ConditionFeatures.for_unit`) and widened. Files saved before the level boxes were stored get
them recomputed from the levels.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from hydrowatch.errors import DataError
from hydrowatch.plant.parameters import PlantParameters

if TYPE_CHECKING:
    from hydrowatch.condition.features import ConditionFeatures

Box = dict[str, tuple[float, float]]


def _boxes(data: Mapping[str, Mapping[str, Any]]) -> dict[str, Box]:
    return {k: {f: (float(b[0]), float(b[1])) for f, b in box.items()} for k, box in data.items()}


def features_to_dict(features: ConditionFeatures) -> dict[str, Any]:
    """JSON-able form of fitted features: parameters and fitted state."""
    f = features
    return {"params": f.get_params(), "nominal_parameters": f.nominal_.to_dict(),
            "states": list(f.states_), "relations": list(f.relations_), "levels": f.levels_,
            "boxes": {k: {j: list(b) for j, b in box.items()} for k, box in f.boxes_.items()},
            "level_boxes": {k: {j: list(b) for j, b in box.items()} for k, box in f.level_boxes_.items()},
            "floors": f.floors_, "unit": f.unit_, "relief_spread": getattr(f, "relief_spread_", 0.0),
            "brake_open": bool(getattr(f, "brake_open_", False)),
            "capacity_known": bool(getattr(f, "capacity_known_", True)),
            "pump_at_limit": getattr(f, "pump_at_limit_", None)}


def features_from_dict(cls: type[ConditionFeatures], data: Mapping[str, Any]) -> ConditionFeatures:
    """Inverse of :func:`features_to_dict`; a :class:`~hydrowatch.errors.DataError` names what is missing."""
    try:
        params = {k: v for k, v in data["params"].items() if k != "kind"}  # "kind" was "scores" (the only one left)
        if data["params"].get("kind", "scores") != "scores":
            raise DataError(f"condition features of kind {data['params']['kind']!r} are no longer supported. "
                            "Retrain with `hydrowatch train`.")
        model = cls(**{**params, "sensors": tuple(params["sensors"])})
        model._parameters()
        model.nominal_ = PlantParameters.from_dict(data["nominal_parameters"])
        model.states_ = tuple(data["states"])
        model.relations_ = tuple(data["relations"])
        model.levels_ = {k: float(v) for k, v in data["levels"].items()}
        model.boxes_ = _boxes(data["boxes"])
        model.floors_ = {k: float(v) for k, v in data["floors"].items()}
        model.unit_ = dict(data.get("unit", {}))
        model.relief_spread_ = float(data.get("relief_spread", 0.0))  # saved since 2026-11-26 (0: determined)
        model.brake_open_ = bool(data.get("brake_open", False))  # saved since 2026-11-27 (condition/standstill.py)
        model.capacity_known_ = bool(data.get("capacity_known", True))  # saved since 2026-12-02 (condition/capacity.py)
        share = data.get("pump_at_limit")  # saved since 2026-12-03 (None: not known)
        model.pump_at_limit_ = None if share is None else float(share)
        if "level_boxes" in data:  # saved since commissioning (boxes moved to a unit are not recomputed)
            model.level_boxes_ = _boxes(data["level_boxes"])
        else:
            model.level_boxes_ = {k: model._box(k, model.nominal_, narrow=True) for k in model.states_}
    except (KeyError, TypeError, IndexError) as exc:
        raise DataError(f"condition features must have params, states, relations, levels, boxes and floors. "
                        f"Missing/bad: {exc}.") from None
    model.feature_names_ = model._names()
    return model
