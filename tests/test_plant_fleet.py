"""Fleets: per-machine parameters, health states, effects, degradation paths and labelled data sets."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.plant.excitation import steps
from hydrowatch.plant.faults import speed_drop, speed_drop_table
from hydrowatch.plant.fleet import (
    SCATTERED_PARAMETERS,
    DegradationPath,
    Fleet,
    MachineSpec,
    scatter_parameters,
    simulate_states,
    state_seeds,
)
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.steady import steady_speed
from hydrowatch.plant.wear import DROP_SEEN, unseen_severity, worn_parameters


def test_scatter_stays_inside_the_spread_and_is_seeded():
    p = PlantParameters()
    a = scatter_parameters(p, 0.03, np.random.default_rng(1))
    b = scatter_parameters(p, 0.03, np.random.default_rng(1))
    assert a == b and a != p
    ratios = np.array([getattr(a, k) / getattr(p, k) for k in SCATTERED_PARAMETERS if getattr(p, k) > 0])
    assert np.all(np.abs(ratios - 1.0) <= 0.03) and np.std(ratios) > 0.005
    assert a.N == p.N and a.noise_speed == p.noise_speed
    with pytest.raises(ParameterError, match="scatter"):
        scatter_parameters(p, 0.7, np.random.default_rng(0))


def test_fixed_states_give_their_speed_drop_against_each_machines_own_healthy_speed():
    specs = [MachineSpec("a"), MachineSpec("b", state="load_alert"), MachineSpec("c", state="motor_leak_warning")]
    fleet = Fleet(specs, scatter=0.04, noise=False, seed=11)
    fleet.settle(2.0, seconds=6.0)
    out = fleet.step(np.full(200, 2.0))
    assert out["speed"].shape == (3, 200)
    for i, expected in enumerate((0.0, 0.30, 0.15)):
        healthy = steady_speed(2.0, fleet.healthy[i])
        assert 1.0 - out["speed"][i, -1] / healthy == pytest.approx(expected, abs=0.005)
    assert fleet.states == ["healthy", "load_alert", "motor_leak_warning"]
    assert list(fleet.drops) == [0.0, 0.30, 0.15]
    assert len({p.TL for p in fleet.healthy}) == 3  # every machine of the build differs


def test_degradation_path_shows_a_fault_appearing():
    path = DegradationPath("valve_coil", start_s=2.0, duration_s=6.0, final_drop=0.30)
    assert [path.drop_at(t) for t in (0.0, 2.0, 5.0, 8.0, 20.0)] == pytest.approx([0, 0, 0.15, 0.30, 0.30])
    fleet = Fleet([MachineSpec("ref"), MachineSpec("worn", path=path)], noise=False, seed=0, update_seconds=0.5)
    fleet.settle(2.0, seconds=6.0)
    labels, speeds = [], []
    for _ in range(12):
        out = fleet.step(np.full(200, 2.0))
        labels.append(fleet.states[1])
        speeds.append(out["speed"][:, -1])
    assert labels[0] == "healthy" and "valve_coil_warning" in labels and labels[-1] == "valve_coil_alert"
    ratio = np.array(speeds)[:, 1] / np.array(speeds)[:, 0]
    assert np.all(np.diff(ratio) <= 1e-6)  # wear only grows
    assert ratio[-1] == pytest.approx(0.70, abs=0.005)  # settled at the final drop
    assert fleet.drops[1] == pytest.approx(0.30)


def test_fleet_machines_have_their_own_commands_effects_and_noise():
    specs = [MachineSpec("a", effects={"valve_deadband": {"d": 0.2}}), MachineSpec("b"), MachineSpec("c")]
    fleet = Fleet(specs, seed=5, fleet="site1")
    command = np.stack([np.full(400, 0.5), np.full(400, 0.5), np.full(400, 3.0)])
    out = fleet.step(command)
    assert out["speed"][0, -100:].mean() < 0.2 * out["speed"][1, -100:].mean()  # deadband swallows 0.5 V
    assert out["speed"][2, -100:].mean() > 4 * out["speed"][1, -100:].mean()
    assert not np.allclose(out["flow"][1], out["flow"][0])
    recordings = fleet.recordings(out)
    assert [r.meta["machine"] for r in recordings] == ["a", "b", "c"]
    assert recordings[2].meta["fleet"] == "site1" and recordings[2].state == "healthy"
    np.testing.assert_array_equal(recordings[1]["speed"], out["speed"][1])
    again = Fleet(specs, seed=5, fleet="site1").step(command)
    np.testing.assert_array_equal(again["torque"], out["torque"])


def test_fleet_refuses_bad_specs():
    with pytest.raises(ParameterError, match="unique"):
        Fleet([MachineSpec("a"), MachineSpec("a")])
    with pytest.raises(ParameterError, match="health state"):
        MachineSpec("a", state="broken")
    with pytest.raises(ParameterError, match="without '/'"):
        MachineSpec("a/b")
    with pytest.raises(ParameterError, match="final_drop"):
        DegradationPath("load", 0.0, 10.0, final_drop=1.5)
    assert Fleet(3).machine_ids == ["m00", "m01", "m02"]


def test_degradation_path_from_a_worn_start_and_accelerating():
    path = DegradationPath("load", start_s=10.0, duration_s=100.0, final_drop=0.36, start_drop=0.06, shape="exp")
    t = np.array([0.0, 10.0, 60.0, 110.0, 500.0])
    lam = np.log(10.0)  # the wear rate at the end is 10x the rate at the start
    expected = 0.06 + 0.30 * np.expm1(lam * np.clip((t - 10.0) / 100.0, 0, 1)) / np.expm1(lam)
    assert path.drop_at(t) == pytest.approx(expected)
    assert path.drop_at(60.0) == pytest.approx(0.06 + 0.30 * (np.sqrt(10.0) - 1) / 9)
    assert isinstance(path.drop_at(60.0), float) and path.top_drop == 0.36
    fleet = Fleet([MachineSpec("w", path=path)], noise=False, seed=0)
    assert fleet.drops[0] == pytest.approx(0.06) and fleet.states == ["healthy"]
    with pytest.raises(ParameterError, match="shape"):
        DegradationPath("load", 0.0, 10.0, shape="cubic")
    with pytest.raises(ParameterError, match="start_drop"):
        DegradationPath("load", 0.0, 10.0, start_drop=-0.1)


@pytest.mark.parametrize("shape", ["linear", "exp"])
def test_a_relief_spring_shut_at_2v_wears_unseen_from_new_without_a_step(shape):
    # a pump at its limit at 2 V: the supply pressure there below the cracking pressure, the relief shut until its
    # spring has weakened some way (as on units whose commissioning had the pump at its limit half of the time)
    unit = PlantParameters().replace(omega_p=0.55 * PlantParameters().omega_p)
    path = DegradationPath("relief_spring", start_s=120.0, duration_s=1800.0, final_drop=0.39, shape=shape)
    table = speed_drop_table("relief_spring", path.top_drop, unit)
    s0 = float(np.interp(DROP_SEEN, *table))
    assert s0 > 0.05  # the severity at which the drop at 2 V starts to move
    t = np.arange(0.0, 400.0)
    worn = [worn_parameters(path, unit, table, float(x)) for x in t]
    severity = np.array([1.0 - p.Pc / unit.Pc for p, _ in worn])
    assert severity[t == 120.0][0] == pytest.approx(s0, rel=1e-6)
    assert np.all(np.diff(severity) >= -1e-12)
    assert np.max(np.diff(severity)) < 0.02 * s0  # before: one step of s0 at the path's start
    assert severity[0] < severity[119]  # wearing unseen before the path's start, at the path's rate
    assert [d for _, d in worn] == pytest.approx(path.drop_at(t))  # the drop, the index and labels unchanged
    assert speed_drop("relief_spring", float(severity[119]), unit) < 5 * DROP_SEEN  # unseen at 2 V indeed
    # a unit whose relief opens at 2 V: the part is new until the path starts, as before
    default = PlantParameters()
    table = speed_drop_table("relief_spring", path.top_drop, default)
    assert worn_parameters(path, default, table, 119.0)[0] == default
    assert unseen_severity(path, table, np.array([0.0, 119.0])) == pytest.approx([0.0, 0.0])
    worn_start = DegradationPath("relief_spring", 120.0, 1800.0, final_drop=0.39, start_drop=0.06, shape=shape)
    assert unseen_severity(worn_start, table, 0.0) == 0.0


def test_state_data_set_is_labelled_and_seeded_per_state():
    recs = list(simulate_states(["healthy", "pump_leak_alert"], seconds=4.0, seed=9))
    assert [r.state for r in recs] == ["healthy", "pump_leak_alert"]
    assert all(len(r) == 800 for r in recs)
    alone = next(simulate_states(["pump_leak_alert"], seconds=4.0, seed=9))
    np.testing.assert_array_equal(alone["speed"], recs[1]["speed"])  # independent of the other states
    assert not np.array_equal(recs[0]["voltage"], recs[1]["voltage"])  # each state its own excitation
    assert recs[1].meta["speed_drop"] == 0.30 and recs[1].meta["fault"] == "pump_leak"
    assert recs[1].meta["seed"] == state_seeds(9, "pump_leak_alert")[1]
    assert 0.0 <= recs[0]["voltage"].min() and recs[0]["voltage"].max() <= 4.0


def test_state_data_set_replays_a_command_in_every_state():
    command = steps(6.0, [1.0, 2.0, 3.0])
    recs = list(simulate_states(["healthy", "load_warning"], command=command, noise=False))
    for r in recs:
        np.testing.assert_array_equal(r["voltage"], command)
    ratio = recs[1]["speed"][790:800].mean() / recs[0]["speed"][790:800].mean()  # settled at 2 V
    assert ratio == pytest.approx(0.85, abs=0.005)


def test_degradation_does_not_depend_on_how_the_stream_is_chunked():
    specs = [MachineSpec("w", path=DegradationPath("load", 0.5, 2.0))]
    command = np.full(700, 2.0)
    whole = Fleet(specs, seed=2, update_seconds=0.25).step(command)
    fleet = Fleet(specs, seed=2, update_seconds=0.25)
    pieces = [fleet.step(command[a:b]) for a, b in ((0, 37), (37, 187), (187, 600), (600, 700))]
    np.testing.assert_array_equal(np.concatenate([p["speed"] for p in pieces], axis=1), whole["speed"])
    assert fleet.states == ["load_alert"]


def test_wear_moves_a_simulators_rows_as_a_fleet_moves_its_paths():
    from hydrowatch.plant.fleet import Wear
    from services.plant import degradation_paths

    path = DegradationPath("motor_leak", 0.0, 30.0, final_drop=0.36, shape="exp")
    fleet = Fleet([MachineSpec("a"), MachineSpec("b", path=path)], seed=1)
    wear = Wear({1: path}, {1: fleet.healthy[1]})
    assert [i for i, _ in wear.due(0.0)] == [1] and wear.due(0.5) == [] and wear.due(0.999999999) != []
    for t in (2.0, 15.0, 29.0, 40.0):  # the same parameters and labels as the fleet's at the same times
        (row, parameters), = wear.due(t)
        assert row == 1 and parameters == fleet._parameters_at(1, t)
        assert wear.states(t, ["healthy", "x"]) == ["healthy", fleet.states[1]]
    assert wear.states(40.0, ["healthy", "x"])[1] == "motor_leak_alert"
    # --degrade of the plant service: named machines, then the others in order
    paths = degradation_paths(["m002=load:0:1.2:60", "pump_leak:0.2:1:30:exp"], ["m000", "m001", "m002"])
    assert sorted(paths) == ["m000", "m002"] and paths["m000"].shape == "exp" and paths["m002"].fault == "load"
    with pytest.raises(ParameterError, match="MACHINE must be one of the fleet's machines"):
        degradation_paths(["m9=load:0:1:60"], ["m000"])
    with pytest.raises(ParameterError, match="at most one path per machine"):
        degradation_paths(["load:0:1:60", "load:0:1:60"], ["m000"])
    with pytest.raises(ParameterError, match="FROM must be a number"):
        degradation_paths(["load:x:1:60"], ["m000"])
