"""An analysis never simulates one model twice on its recording (issue 12, item 5): a model kept for as many samples
or more is taken, the first samples of a longer simulation serve a head of the recording, the numbers are those a
simulation gives, and two analyses keep their own."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hydrowatch.gap import align as aligning
from hydrowatch.gap import simulations
from hydrowatch.gap.align import align, simulate_sensors
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

DESIGN = PlantParameters()
UNIT = DESIGN.replace(Kq=DESIGN.Kq * 1.2)


def _recording() -> aligning.AlignedRecording:
    return align(simulate(filtered_noise(10.0, (-4.0, 4.0), seed=3), UNIT, None, seed=3))


def _counted(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    models: list[int] = []
    original = aligning._simulate_models

    def counted(*args: object) -> np.ndarray:
        models.append(len(args[1]))  # type: ignore[arg-type]
        return original(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(aligning, "_simulate_models", counted)
    return models


def test_a_model_kept_is_not_simulated_again_and_serves_the_heads(monkeypatch: pytest.MonkeyPatch) -> None:
    aligned = _recording()
    backlash = {"gear_backlash": {"b": 0.02}}
    fresh = simulate_sensors(_recording(), [DESIGN, UNIT, DESIGN], [None, None, backlash])  # another analysis
    fresh_head = simulate_sensors(_recording().head(4.0), [DESIGN], [backlash])
    models = _counted(monkeypatch)
    first = simulate_sensors(aligned, [DESIGN, UNIT, DESIGN, UNIT], [None, None, backlash, None])
    assert models == [3]  # the same model twice in one call is simulated once
    assert np.array_equal(first[:3], fresh) and np.array_equal(first[3], first[1])
    again = simulate_sensors(aligned, [UNIT, DESIGN], [None, backlash])
    head = simulate_sensors(aligned.head(4.0), [DESIGN], [backlash])
    short = simulate_sensors(aligned, [DESIGN], [None], stop=300)
    assert models == [3]
    assert np.array_equal(again, first[[1, 2]]) and np.array_equal(short[0], first[0][:, :300])
    # The first samples of the whole record's simulation are the head's simulation, bit for bit.
    assert np.array_equal(head, fresh_head)
    # Another model (one parameter one ulp away) is simulated.
    simulate_sensors(aligned, [DESIGN.replace(Kq=np.nextafter(DESIGN.Kq, 1.0))], [None])
    assert models == [3, 1]
    assert aligned.simulations.reused == 4 and aligned.simulations.simulated == 4


def test_two_analyses_keep_their_own_and_a_bounded_amount(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two analyses of the same samples (two recording objects, as two threads of one process would hold) neither
    see nor push out each other's simulations (issue 12: the Jacobian kept for a continuation was one slot for the
    process until this pass); each keeps at most LIMIT_BYTES per prediction length, and nothing once emptied."""
    one, other = _recording(), _recording()
    models = _counted(monkeypatch)
    simulate_sensors(one, [DESIGN], [None])
    simulate_sensors(other, [DESIGN], [None])
    assert models == [1, 1] and len(one.simulations) == len(other.simulations) == 1
    kept = one.simulations
    size = 3 * one.t.size * 8
    monkeypatch.setattr(simulations, "LIMIT_BYTES", 2 * size)
    simulate_sensors(one, [DESIGN.replace(TL=DESIGN.TL * (1 + 0.01 * i)) for i in range(1, 4)], [None] * 3)
    assert len(kept) == 2  # the oldest went
    simulate_sensors(one, [DESIGN], [None])
    assert models == [1, 1, 3, 1]
    # The heads of a screen have their own share: thirty of them do not push out the whole-record simulations.
    simulate_sensors(one.head(1.0), [DESIGN.replace(BL=DESIGN.BL * (1 + 0.01 * i)) for i in range(1, 31)], [None] * 30)
    simulate_sensors(one, [DESIGN, DESIGN.replace(TL=DESIGN.TL * 1.03)], [None, None])
    assert models == [1, 1, 3, 1, 30]
    kept.clear()
    assert len(kept) == 0 and kept.simulated == 35


def test_a_copy_with_another_command_is_simulated_afresh(monkeypatch: pytest.MonkeyPatch) -> None:
    """The kept simulations are of one command: a recording object copied with another command (or start time) keeps
    the same keeper but is never served from it."""
    aligned = _recording()
    simulate_sensors(aligned, [DESIGN], [None])
    models = _counted(monkeypatch)
    louder = replace(aligned, voltage=aligned.voltage * 0.9)
    later = replace(aligned, t=aligned.t + 1.0)
    assert louder.simulations is aligned.simulations
    moved = simulate_sensors(louder, [DESIGN], [None])
    simulate_sensors(later, [DESIGN], [None])
    assert models == [1, 1]
    assert np.array_equal(moved, simulate_sensors(align_like(louder), [DESIGN], [None]))


def align_like(aligned: aligning.AlignedRecording) -> aligning.AlignedRecording:
    """The same samples in a recording object of their own (its own kept simulations)."""
    return replace(aligned, simulations=simulations.Simulations())
