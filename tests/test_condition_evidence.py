"""Evidence pooled over a machine's windows: look-alike holds resolved, unseen look-alikes rejected."""

from __future__ import annotations

import json
import weakref

import numpy as np
import pytest
from test_condition_model import windows_of

from hydrowatch.condition import (
    ConditionModel,
    ConditionStream,
    EvidenceLayout,
    EvidenceSmoother,
    trailing_evidence,
)
from hydrowatch.condition.evidence import (
    HOLD_SPAN,
    SEVERITY_TOLERANCE,
    distinct_points,
    operating_points,
    trailing_count,
    trailing_spans,
    trailing_support,
)
from hydrowatch.condition.model import CLEAR_FACTOR, CLEAR_WINDOWS, POOLED_EXCESS
from hydrowatch.condition.ratios import NO_OTHER_EXPLANATION
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.plant.excitation import duty_cycle, filtered_noise

STATES = ("healthy", "valve_coil_warning", "valve_coil_alert", "relief_spring_warning", "pump_leak_warning",
          "valve_leak_warning")


@pytest.fixture(scope="module")
def trained():
    train = windows_of(STATES, filtered_noise(40, (0, 4), seed=7), seed=8)
    return train, ConditionModel().fit(train)


def test_trailing_evidence_pools_valid_windows_only():
    rows = np.array([[1.0, 4.0], [np.nan, np.nan], [4.0, 1.0], [2.0, 2.0]])
    geometric, arithmetic = trailing_evidence(rows, 2)
    np.testing.assert_allclose(geometric[[0, 2, 3]], [[1.0, 4.0], [2.0, 2.0], [np.sqrt(8), np.sqrt(2)]])
    np.testing.assert_allclose(arithmetic[3], [3.0, 1.5])  # the NaN row is skipped, not counted
    assert np.isnan(geometric[1]).all()
    smoother = EvidenceSmoother(n_windows=2)
    assert smoother.get() is None
    for row in rows:
        smoother.update(row)
    np.testing.assert_allclose(smoother.get()[0], geometric[3])
    with pytest.raises(ParameterError):
        EvidenceSmoother(n_windows=0)


def test_one_machine_has_one_severity():
    # 2 states, 1 relation: state 1's own fault; windows agree on it (0.30), or differ within the tolerance
    # or 0.035 beyond it.
    layout = EvidenceLayout(columns=np.array([-1, 1]), bounds=np.array([[[0, 0], [0.1, 0.5]], [[0, 0], [0.29, 0.31]]]))
    ratios = np.ones((2, 4))  # band (2 states) and level (2 states) ratios
    agree = np.column_stack([ratios, [[0.0, 0.30], [0.0, 0.30]], [[0.0, 100.0], [0.0, 100.0]],
                             np.full((2, 4), NO_OTHER_EXPLANATION)])  # nothing else explains the relation
    g, a = trailing_evidence(agree, 2, layout)
    np.testing.assert_allclose(a[1], 1.0)
    close, differ = agree.copy(), agree.copy()
    delta = SEVERITY_TOLERANCE * 0.30
    close[:, 5], differ[:, 5] = [0.30 - 0.9 * delta, 0.30 + 0.9 * delta], [0.30 - delta - 0.035, 0.30 + delta + 0.035]
    g, a = trailing_evidence(close, 2, layout)
    np.testing.assert_allclose(a[1], 1.0)  # within δ = SEVERITY_TOLERANCE · 0.30 of the common 0.30: no cost
    g, a = trailing_evidence(differ, 2, layout)
    # Band box [0.1, 0.5] holds both alone; together each may sit at most δ from 0.30: 100·0.035² more.
    # The level box [0.29, 0.31] held them at its edges already, inside the tolerance: nothing more.
    np.testing.assert_allclose(a[1, [1, 3]], [1.0 + 100 * 0.035**2, 1.0])
    # The other valve-side faults in the state's band box explain the relation at a ratio of 1.05: a window costs
    # the shared severity no more than that (the quadratic model's 1.1225 would overstate it).
    explained = differ.copy()
    explained[:, 9] = 1.05  # the band box's "others" column of state 1 (after ratios, severities, weights)
    np.testing.assert_allclose(trailing_evidence(explained, 2, layout)[1][1, 1], 1.05)
    np.testing.assert_allclose(trailing_evidence(explained, 2, layout)[0][1, 1],
                               np.exp(0.5 * (np.log(1.05) + np.log(1.05))))
    with pytest.raises(DataError):
        trailing_evidence(agree[:, :9], 2, layout)


def test_pooling_resolves_look_alike_holds(trained):
    _, model = trained
    holds = np.concatenate([np.full(2000, v) for v in (2.0, 0.8, 2.1, 3.3, 1.9, 1.4, 2.0, 2.9)])
    test = windows_of(STATES, holds, seed=9)
    acc = {n: np.mean(np.concatenate([model.predict(w, smoothing=n) == s for s, w in test.items()])) for n in (1, 6)}
    assert acc[1] < 0.85 and acc[6] > 0.9  # 81 % → 93 %: only the first windows, all near 2 V, stay ambiguous


def test_an_unseen_fault_is_rejected_per_machine(trained):
    train, _ = trained
    model = ConditionModel().fit({s: w for s, w in train.items() if not s.startswith("relief_spring")})
    test = windows_of(("pump_leak_alert", "valve_leak_alert", "valve_coil_alert", "healthy"),
                      duty_cycle(120, (0, 4), seed=3), seed=4)
    unknown = {n: {s: np.mean(model.predict(w, smoothing=n) == "unknown") for s, w in test.items()} for n in (1, 12)}
    # Alerts of faults trained only at their warning level: 37.5 / 66.7 % per window, 95.8 / 100 % pooled over 12
    # windows; known states never. (An unseen relief_spring_alert, valve_coil_alert's look-alike on this duty cycle,
    # read unknown in 25 % of pooled windows with the earlier pooled limit 1.0 and in none with POOLED_EXCESS 2.0,
    # the price of known states of other units and days no longer reading unknown pooled: docs/unseen-units.md.)
    assert unknown[1]["pump_leak_alert"] < 0.5 < 0.9 < unknown[12]["pump_leak_alert"]
    assert unknown[1]["valve_leak_alert"] < 0.8 < 0.95 < unknown[12]["valve_leak_alert"]
    assert unknown[12]["valve_coil_alert"] == 0.0 and unknown[12]["healthy"] == 0.0


def test_stream_matches_batch_pooling(trained):
    train, model = trained
    w = train["pump_leak_warning"][:5].copy()
    w[2, 10:20, 1] = np.nan  # a gap: skipped, the history is kept
    assert model.pools_open_set()
    stream = ConditionStream(model, n_windows=3)
    assert stream.get() is None
    for row in w:
        stream.update(row)
    batch, scores = model.judge_with_scores(w, smoothing=3)
    np.testing.assert_array_equal(scores, model.features_.transform(w))
    assert batch[2].state == "invalid"
    assert stream.get().state == batch[-1].state == "pump_leak_warning"
    assert stream.get().probabilities == pytest.approx(batch[-1].probabilities)


def test_a_stream_keeps_copies_of_the_batched_flags_it_is_given_not_the_batch(trained):
    """A scorer hands each machine a row of one batched array of leads; the pool must not keep that array alive (a
    view in a deque held every batch's array for a pool's windows, and their frees fragmented the heap)."""
    train, model = trained
    w = train["pump_leak_warning"][:4]
    rows = model.features_.transform_evidence(w)
    width = 2 * len(model.features_.feature_names_)
    stream = ConditionStream(model, n_windows=3)
    batches = []
    for row, point in zip(rows, operating_points(w)):
        batch = np.repeat(model.alone_leads(row[None, :width]), 500, axis=0)  # as many machines' flags
        batches.append(weakref.ref(batch))
        stream.update_features(row, float(point), False, batch[7])
        del batch
    assert [b() for b in batches] == [None] * 4
    again = ConditionStream(model, n_windows=3)
    for row in w:
        again.update(row)
    got, want = stream.evidence(), again.evidence()
    assert got[3:5] == want[3:5] == (3, 0)
    np.testing.assert_array_equal(got[5], want[5])
    np.testing.assert_array_equal(got[0], want[0])


def test_pooled_excess_is_saved_and_older_directories_load(trained, tmp_path):
    train, _ = trained
    model = ConditionModel(pooled_excess=0.5).fit({s: train[s] for s in STATES[:3]})
    model.save(tmp_path / "m")
    assert ConditionModel.load(tmp_path / "m").pooled_excess_ == 0.5
    (tmp_path / "m" / "condition_model.json").unlink()  # as round 2 wrote it
    assert ConditionModel.load(tmp_path / "m").pooled_excess_ == POOLED_EXCESS
    (tmp_path / "m" / "condition_model.json").write_text(json.dumps({"format": 99}))
    with pytest.raises(DataError, match="format"):
        ConditionModel.load(tmp_path / "m")


def test_a_pool_reads_unknown_only_when_a_window_did_or_its_excess_is_clear(trained):
    # Pooling never makes a verdict worse (issue 11 item 2): a known state that misfits by a little in every window
    # (a severity just outside its band on another unit or day) is rejected by no window alone but by the pooled
    # mean; it keeps its name unless one of the pooled windows read unknown alone or the excess is clear
    # (CLEAR_FACTOR × pooled_excess).
    _, model = trained
    states = list(model.features_.states_)
    relations = len(model.features_.relations_)
    k = states.index("pump_leak_warning")

    def row(excess: float) -> np.ndarray:
        band = np.full((relations, len(states)), 50.0)
        band[:, k] = 1.0 + excess / relations  # state k misses by ``excess`` summed over the relations
        return np.concatenate([band.ravel(), band.ravel()])

    limit = model.pooled_excess_
    middle, clear = 0.5 * (1.0 + CLEAR_FACTOR) * limit, 1.1 * CLEAR_FACTOR * limit
    assert relations + middle < model.open_set_.thresholds_[k]  # no window of the first kind is unknown alone
    rows = np.stack([row(middle), row(middle), row(clear)])
    assert not model.alone_unknown(rows[:1]).any()
    everything = np.ones((3, len(states)), dtype=bool)  # every state supported (SUPPORT_POINTS)

    def states_of(support: list[int]) -> list[str]:
        return [v.state for v in model.judge_pooled(rows, rows, rows, windows=np.full(3, 12), supported=everything,
                                                    support=np.array(support), spans=np.ones(3, dtype=bool))]

    assert states_of([0, 1, 0]) == ["pump_leak_warning", "unknown", "unknown"]
    assert states_of([0, 0, 0])[0] == "pump_leak_warning"
    assert states_of([0, 0, 0])[2] == "unknown"  # clear, over 12 windows
    # over fewer than CLEAR_WINDOWS windows (a recording's first) the clear limit does not judge: the window itself did
    short = model.judge_pooled(rows, rows, rows, windows=np.array([12, 12, CLEAR_WINDOWS - 1]), support=np.zeros(3),
                               supported=everything, spans=np.ones(3, dtype=bool))
    assert short[2].state == "pump_leak_warning"
    # nor over pools of one hold (SUPPORT_POINTS): their windows share the relations' model error, and each window's
    # own open-set verdict stands, whatever the pool's excess or how many windows read unknown alone (issue 11, fresh
    # seed 2069: pump_leak_alert machines in a 3.2 V and a 2.9 V hold read unknown pooled, right alone)
    alone = [v.state for v in model.judge_evidence(rows, rows)]
    assert alone[2] == "pump_leak_warning"
    one_hold = model.judge_pooled(rows, rows, rows, windows=np.full(3, 12), support=np.array([0, 1, 0]),
                                  supported=everything, spans=np.zeros(3, dtype=bool))
    assert [v.state for v in one_hold] == alone
    # the streaming form counts the points of its own windows: three clear windows of one hold keep the name,
    # the same three at two points read unknown
    full = np.concatenate([row(clear), np.zeros(2 * len(states)), np.full(2 * len(states), NO_OTHER_EXPLANATION)])

    def streamed(points: list[float]) -> str:
        stream = ConditionStream(model, n_windows=3)
        for point in points:
            stream.update_features(full, point, alone_unknown=False)
        got = stream.get()
        assert got is not None
        return got.state

    assert streamed([2.0, 2.0, 2.0]) == "pump_leak_warning"
    assert streamed([2.0, 3.0, 2.0]) == "unknown"
    # the batch form counts the windows that read unknown alone over the same trailing windows it pools
    flags = np.array([True, False, False, True, False])
    ratios = np.ones((5, 2))
    ratios[2] = np.nan  # an invalid window is neither pooled nor counted
    np.testing.assert_array_equal(trailing_count(flags, ratios, 2), [1, 1, 0, 1, 1])


def test_operating_points_tell_holds_from_moving_windows():
    hold = np.full((1000, 4), 1.0)
    hold[:, 0] = 2.0
    ramp = hold.copy()
    ramp[:, 0] = np.linspace(2.0, 2.5, 1000)
    near = hold.copy()
    near[:, 0] = 2.0 + 0.5 * HOLD_SPAN  # another hold within HOLD_SPAN of the first: the same point
    points = operating_points(np.stack([hold, ramp, near, hold + [1.0, 0, 0, 0]]))
    np.testing.assert_allclose(points[[0, 2, 3]], [2.0, 2.0 + 0.5 * HOLD_SPAN, 3.0])
    assert np.isnan(points[1])
    assert distinct_points(points) == 3  # the 2 V holds once, the ramp, the 3 V hold
    assert distinct_points(points[[0, 2]]) == 1
    assert distinct_points(np.array([np.nan, np.nan])) == 2  # each moving window a point of its own
    with pytest.raises(DataError, match="command first"):
        operating_points(np.zeros((3, 10)))


def test_a_pooled_fault_needs_windows_at_two_operating_points(trained):
    # Issue 11 item 2: windows of one hold share the relations' model error there; a fault that only they prefer to
    # healthy (a commissioned unit's hold at the pump's limit) must not be carried over the windows beside them.
    _, model = trained
    states = list(model.features_.states_)
    relations = len(model.features_.relations_)
    k, h = states.index("relief_spring_warning"), states.index("healthy")
    band = np.full((5, relations, len(states)), 50.0)
    band[:, :, [h, k]] = 1.0  # healthy and the fault tie in every window (healthy wins ties by its margin)
    band[2:4, 0, h] = 1.5  # two windows prefer the fault: log 1.5 = 0.41 beyond the margin
    ratios = np.concatenate([band.reshape(5, -1)] * 2, axis=1)
    leads = model.alone_leads(ratios)
    assert leads[2:4, k].all() and not leads[[0, 1, 4], k].any() and not leads[:, h].any()
    decision = np.exp(np.cumsum(np.log(ratios), axis=0) / np.arange(1, 6)[:, None])  # pooled from the first window
    pooled = {"windows": np.arange(1, 6), "support": np.zeros(5)}

    def last(points: list[float]) -> str:
        supported = trailing_support(leads, np.array(points), ratios, 5)
        spans = trailing_spans(np.array(points), ratios, 5)
        return model.judge_pooled(decision, decision, ratios, **pooled, supported=supported, spans=spans)[-1].state

    assert last([np.nan, np.nan, 3.49, 3.49, 2.0]) == "healthy"  # one hold: the last window's own verdict
    assert last([np.nan, np.nan, 3.49, np.nan, 2.0]) == "relief_spring_warning"  # a hold and a ramp: two points
    carried = model.judge_pooled(decision, decision, ratios, **pooled, supported=np.ones((5, len(states)), bool),
                                 spans=np.ones(5, dtype=bool))
    assert carried[-1].state == "relief_spring_warning"  # without the rule the pool carries it
    # the streaming form asks the same
    stream = ConditionStream(model, n_windows=5)
    rows = np.concatenate([ratios, np.zeros((5, 2 * len(states))), np.full((5, 2 * len(states)), NO_OTHER_EXPLANATION)],
                          axis=1)  # no severity to share
    for row, point in zip(rows, [np.nan, np.nan, 3.49, 3.49, 2.0]):
        stream.update_features(row, point, alone_unknown=False)
    evidence = stream.evidence()
    assert evidence is not None and not evidence[5][k]
