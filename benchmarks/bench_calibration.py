"""Calibration of the parity rule's probabilities on commands unlike training (issue 5).

Trains the parity model on one 200 s filtered-noise 0–4 V recording per state (the study's 7
and the extended 13), then scores separately simulated recordings: filtered noise like training
(other seed), a working duty cycle, and a duty cycle with 3 machines per state whose severities
are spread inside their bands. For each set, per window and pooled over a machine's last 12
windows (the scorer's default), it prints the accuracy of the decision, the expected calibration
error (ECE, 15 bins), the share of wrong verdicts that carried p > 0.99, and the mean p of
healthy windows; for the rule as it was (fitted temperature: 0.02, the floor of
``fit_temperature``), as it is (``ParityRule`` defaults: temperature floor 0.1) and with the
optional healthy prior (0.5). Accuracy counts the decision alone (the open-set rule is not
applied here).

Run: ``python benchmarks/bench_calibration.py [--train-seconds 200] [--test-seconds 100]``.
"""

from __future__ import annotations

import argparse

import numpy as np
from bench_command_invariance import simulate

from hydrowatch.condition import ConditionModel, pooled_windows, trailing_evidence
from hydrowatch.condition.rule import ParityRule
from hydrowatch.health.metrics import expected_calibration_error
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import EXTENDED_STATES, STUDY_STATES, random_state_parameters, state_parameters

POOL = 12


def test_sets(states: tuple[str, ...], test_s: float) -> dict[str, dict[str, np.ndarray]]:
    """Raw windows per machine (``state#i`` for several machines of one state) of each test condition."""
    nominal = [state_parameters(s) for s in states]
    rng = np.random.default_rng(5)
    spread = [f"{s}#{i}" for i in range(3) for s in states]
    spread_params = [random_state_parameters(m.split("#")[0], rng)[0] for m in spread]
    return {
        "like training (other seed)": simulate(nominal, list(states), filtered_noise(test_s, (0, 4), seed=2), seed=12),
        "duty cycle": simulate(nominal, list(states), duty_cycle(2 * test_s, (0, 4), seed=4), seed=14),
        "spread in bands, duty cycle": simulate(spread_params, spread, duty_cycle(2 * test_s, (0, 4), seed=21),
                                                seed=22),
    }


def report(rule: ParityRule, model: ConditionModel, machines: dict[str, np.ndarray]) -> str:
    """Accuracy, ECE, wrong verdicts with p > 0.99 and mean p(healthy) of healthy windows, per window and pooled."""
    classes = rule.classes_.tolist()
    layout = model.features_.evidence_layout()
    width = 2 * len(model.features_.feature_names_)
    out = []
    for pooled in (False, True):
        proba, truth = [], []
        for machine, w in machines.items():
            rows = model.features_.transform_evidence(w)
            x = trailing_evidence(rows, POOL, layout)[0] if pooled else rows[:, :width]
            ok = np.all(np.isfinite(x), axis=1)
            proba.append(rule.predict_proba(x[ok], pooled_windows(rows, POOL)[ok] if pooled else None))
            truth += [classes.index(machine.split("#")[0])] * int(ok.sum())
        p, y = np.concatenate(proba), np.array(truth)
        wrong = p.argmax(axis=1) != y
        sure = float(np.mean(p.max(axis=1)[wrong] > 0.99)) if wrong.any() else 0.0
        healthy = float(p[y == classes.index("healthy"), classes.index("healthy")].mean())
        ece = expected_calibration_error(p, y)
        out.append(f"{'pooled' if pooled else 'window'} acc {100 * (1 - wrong.mean()):5.1f}% "
                   f"ECE {ece:.3f} wrong p>0.99 {100 * sure:3.0f}% p(healthy) {healthy:.2f}")
    return " | ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train-seconds", type=float, default=200.0)
    ap.add_argument("--test-seconds", type=float, default=100.0)
    args = ap.parse_args()
    for states in (tuple(STUDY_STATES), tuple(EXTENDED_STATES)):
        train = simulate([state_parameters(s) for s in states], list(states),
                         filtered_noise(args.train_seconds, (0, 4), seed=1), seed=11)
        model = ConditionModel().fit(train)
        now = model.decision_
        assert isinstance(now, ParityRule)
        rows = _training_rows(model, train)
        before = ParityRule(min_temperature=0.02).fit(*rows, classes=now.classes_.tolist())
        prior = ParityRule(healthy_prior=0.5).fit(*rows, classes=now.classes_.tolist())
        print(f"\n=== {len(states)} states: temperature fitted {before.temperature_:.3f}, used {now.temperature_:.3f}")
        for name, machines in test_sets(states, args.test_seconds).items():
            print(f"  {name}")
            print(f"    before: {report(before, model, machines)}")
            print(f"    now:    {report(now, model, machines)}")
            print(f"    prior:  {report(prior, model, machines)}", flush=True)


def _training_rows(model: ConditionModel, train: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    rows = [model.features_.transform_with_levels(train[s]) for s in model.features_.states_]
    labels = np.concatenate([[s] * len(r) for s, r in zip(model.features_.states_, rows)])
    return np.concatenate(rows), labels


if __name__ == "__main__":
    main()
