"""Parity localisation of the gap analysis: which component relation breaks, and where."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.gap.relations import BREAK_RATIO, RELATIONS, STRUCTURE, RelationCheck, check_relations, describe
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate
from hydrowatch.recording import SENSORS

PLANT = PlantParameters()
COMMAND = filtered_noise(20.0, (0.0, 4.0), seed=3)
NOISE = np.array([PLANT.noise_flow, PLANT.noise_speed, PLANT.noise_torque])
MASK = np.arange(COMMAND.size) >= 200


def checks(effects: dict | None, plant: PlantParameters = PLANT) -> dict[str, RelationCheck]:
    """The relations on a noisy recording of ``plant`` with ``effects``, as after a diagnosis that found
    the plant's parameters (the floor) and its effects (the trajectory of the noise reference)."""
    measured, model, nominal = (np.vstack([simulate(COMMAND, plant, e, seed=4, noise=noisy)[s] for s in SENSORS])
                                for e, noisy in ((effects, True), (effects, False), (None, False)))
    structure = {name: model if not set(effects or {}) & STRUCTURE[name] else nominal for name in RELATIONS}
    found = check_relations(COMMAND, measured, structure, model, NOISE, plant, MASK)
    assert [c.name for c in found] == list(RELATIONS)
    return {c.name: c for c in found}


def test_relations_hold_on_a_plant_that_only_differs_in_parameters() -> None:
    plant = PLANT.replace(TL=PLANT.TL * 1.2, BL=PLANT.BL * 0.85, Ctm=PLANT.Ctm * 1.3)
    found = checks(None, plant)
    for c in found.values():
        assert 0.85 < c.ratio < 1.15 and not c.broken
    assert describe(list(found.values())).startswith("Every component relation")


@pytest.mark.parametrize(
    ("effects", "broken", "holds", "family"),
    [
        ({"quadratic_drag": {"Kd": 0.03}}, {"load"}, {"motor", "valve"}, "speed"),
        ({"valve_deadband": {"d": 0.1}}, {"valve"}, {"motor"}, "command"),
        ({"valve_saturation": {"x_max": 0.5}}, {"valve"}, {"load", "motor"}, "command"),
        ({"shaft_compliance": {"G": 800.0}}, {"load"}, {"motor", "valve"}, None),
        # a flow sensor's own lag: both relations with the flow sensor break, the load side holds
        ({"sensor_lowpass": {"sensor": 0.0, "tau": 0.03}}, {"motor", "valve"}, {"load"}, None),
    ],
)
def test_the_component_relation_that_breaks_names_the_component(effects: dict, broken: set[str], holds: set[str],
                                                                 family: str | None) -> None:
    found = checks(effects)
    worst = max(found.values(), key=lambda c: c.ratio)
    assert worst.name in broken and worst.ratio > 1.4 * BREAK_RATIO
    assert all(found[name].broken for name in broken)
    assert all(not found[name].broken for name in holds)
    if family is not None:
        assert worst.regime.family == family
    text = describe(list(found.values()))
    assert f"the {worst.name} relation breaks" in text and worst.regime.label in text
    assert ("flow sensor" in text) == (broken == {"motor", "valve"})


def test_deadband_breaks_the_valve_relation_at_low_command() -> None:
    valve = checks({"valve_deadband": {"d": 0.1}})["valve"]
    assert valve.regime.label.startswith("command 0")
    assert valve.regime.share > 0.4
    assert valve.as_dict()["unit"] == "L/min"
