"""Chunk hygiene: one rule for every health method decides which chunks are clean and which windows break."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.health.plan import DataPlan
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.chunks import DT, Break, Chunk, ChunkBatch, clean_chunks, cut_short
from hydrowatch.training.online import OnlineScorer
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.trainer import train
from hydrowatch.verdict import INVALID

STATES = ["healthy", "load_alert"]
COLUMNS = ["voltage", "flow", "speed", "torque"]


def _chunk(machine: str, t0: float, n: int = 5, **overrides: np.ndarray | None) -> Chunk:
    t = t0 + DT * np.arange(n)
    channels = {c: np.linspace(1.0, 2.0, n) for c in COLUMNS}
    for name, values in overrides.items():
        if values is None:
            del channels[name]
        else:
            channels[name] = values
    return Chunk(machine, t, channels)


def test_clean_chunks_flags_every_kind_of_unclean_chunk() -> None:
    spaced = 1.0 + DT * np.array([0, 1, 2, 4, 5])
    chunks = [
        _chunk("clean", 1.0),
        _chunk("nan", 1.0, flow=np.array([1.0, np.nan, 1.0, 1.0, 1.0])),
        _chunk("absent", 1.0, torque=None),
        _chunk("defaulted", 1.0, temperature=np.full(5, 40.0), torque=None),
        Chunk("irregular", spaced, {c: np.ones(5) for c in COLUMNS}),
        _chunk("twice", 1.0), _chunk("twice", 1.0 + 5 * DT),
        _chunk("short", 1.0, n=1),
        _chunk("late", 1.0),
        _chunk("gap", 1.0),
        _chunk("nan_t", 1.0),
    ]
    chunks[-1].t[2] = np.nan
    batch = ChunkBatch.from_chunks(chunks, COLUMNS)
    machines = batch.machines
    once = np.array([machines.count(m) == 1 for m in machines])
    expected = np.array([np.nan] * len(chunks))
    expected[machines.index("late")] = 1.5  # the chunk starts before its machine's next sample
    expected[machines.index("gap")] = 1.0 - 3 * DT  # … and after it: samples were lost
    expected[machines.index("clean")] = 1.0 + 0.2 * DT  # within tolerance
    got = clean_chunks(batch, COLUMNS, expected, once, {"torque": 0.0})
    assert dict(zip(machines, got.tolist())) | {"absent": bool(got[2])} == {
        "clean": True, "nan": False, "absent": True, "defaulted": True, "irregular": False, "twice": False,
        "short": False, "late": False, "gap": False, "nan_t": False}
    assert not clean_chunks(batch, COLUMNS, expected, once, {})[machines.index("absent")]  # no default: unclean


def test_cut_short_only_when_the_window_in_progress_has_samples() -> None:
    brk = Break("gap of 0.100 s before t=3.000 s", 2.9)
    assert cut_short("m", 200, 200, 1.0, brk) is None
    verdict = cut_short("m", 200, 201, 1.0, brk)
    assert verdict is not None and verdict.start_s == 1.0 + 200 * DT and verdict.end_s == 2.9
    assert verdict.verdict.state == INVALID and verdict.verdict.reason == brk.reason


@pytest.fixture(scope="module")
def bundles() -> dict[str, ModelBundle]:
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    return {m: train(grouped, TrainingSettings(method=m, reference="bj", plan=plan)).bundle
            for m in ("entropy", "parity")}


def _faulty_feed(scorer: OnlineScorer, recordings: list) -> list:
    """0.1 s chunks of every recording, with a lost chunk, a NaN burst, a late chunk and irregular times."""
    verdicts = []
    n = len(recordings[0])
    for k in range(0, n - 20, 20):
        chunks = []
        for i, r in enumerate(recordings):
            if i == 0 and k == 1500:
                continue  # lost on the way: a gap
            part = slice(k, k + 20)
            channels = {c: r[c][part].copy() for c in COLUMNS}
            t = r.t[part].copy()
            if i == 1 and k == 2300:
                channels["speed"][7] = np.nan
            if i == 1 and k == 3700:
                t[10:] += 0.5 * DT + 1e-4  # irregular spacing inside the chunk
            chunks.append(Chunk(r.state, t, channels))
            if i == 0 and k == 4400:
                chunks.append(Chunk(r.state, r.t[k - 40:k - 20], {c: r[c][k - 40:k - 20] for c in COLUMNS}))  # late
        verdicts += scorer.update(chunks)
    return verdicts


def test_both_methods_invalidate_the_same_windows_for_the_same_reasons(bundles: dict[str, ModelBundle]) -> None:
    recordings = list(simulate_states(STATES, seconds=30, seed=4))
    invalid = {}
    for method, bundle in bundles.items():
        verdicts = _faulty_feed(OnlineScorer(bundle), recordings)
        invalid[method] = [(v.machine, round(v.end_s, 6), v.verdict.reason) for v in verdicts
                           if v.verdict.state == INVALID]
        assert any(v.verdict.state != INVALID for v in verdicts)
    assert len(invalid["parity"]) >= 4  # (the shifted times also make the next chunk late)
    reasons = " ".join(r for _, _, r in invalid["parity"])
    assert all(word in reasons for word in ("gap", "NaN in speed", "irregular", "late"))
    assert invalid["entropy"] == invalid["parity"]
