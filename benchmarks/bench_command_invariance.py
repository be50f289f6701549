"""Accuracy of health verdicts when the command differs from the identification experiment (issue 5).

Approaches (all trained on one filtered-noise 0–4 V recording per state, as in the study):

- ``study``: a healthy reference model per sensor (a linear ARX one-step predictor fitted by
  least squares, standing in for the study's NARX, which costs minutes to train) + Gaussian base
  distributions + relative entropies (Eq. 5.3) + the study's classifier (section 6.5);
- ``conditioned``: the same with base distributions conditioned on the operating point (one set
  per command level bin, the window's mean command picks the bin);
- ``parity-mlp``: hydrowatch.condition parity scores + the study's classifier;
- ``parity``: hydrowatch.condition parity scores + the nearest-physics rule (the default).

Test conditions: other seed (like training), another operating day (leakages +15 %, load +3 %),
a working duty cycle (holds, ramps, steps), slow noise (pole 0.98), a narrow range (1–3 V),
another range (1–4 V), severities spread in their bands, oil 10 °C warmer (thermal_drift), the
open set, and sensor subsets. Accuracy = share of windows whose verdict is the true state
(``unknown`` counts as wrong, except in the open-set row where it is the right answer).

Round 3 adds: evidence pooled over a machine's windows (``smoothing``: accuracy and delay after
a change of state, open set per machine) and the sensor subsets with per-state fills. Round 4
adds machines with severities spread in their bands on a long duty cycle (accuracy once each
machine's pool is full, "settled"), the confusion pairs in holds and moving windows, and the
open set once the pool is full.

Run: ``python benchmarks/bench_command_invariance.py [--train-seconds 300] [--test-seconds 150]
[--quick]``. Timings are taken on a shared 2-core machine (pessimistic): the scoring cost is
printed as CPU time of this process (BLAS pinned to one thread) and as wall time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from hydrowatch.condition import ConditionFeatures, ConditionModel
from hydrowatch.condition.evidence import operating_points
from hydrowatch.health.classifier import HealthClassifier
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.plant import PlantParameters, PlantSimulator
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import EXTENDED_STATES, STUDY_STATES, random_state_parameters, state_parameters

CHANNELS = ("voltage", "flow", "speed", "torque", "temperature")
W = 1000


def simulate(params: list[PlantParameters], labels: list[str], u: np.ndarray, seed: int,
             effects: dict | None = None) -> dict[str, np.ndarray]:
    """Raw windows per label, (n, W, 5) with the oil temperature last; machines sharing a label are stacked."""
    sim = PlantSimulator(params, effects, seed=seed)
    sim.settle(float(u[0]))
    out = sim.step(np.broadcast_to(u, (len(params), u.size)))
    n = u.size // W * W
    data: dict[str, list[np.ndarray]] = {}
    for i, label in enumerate(labels):
        data.setdefault(label, []).append(np.stack([out[c][i, :n].reshape(-1, W) for c in CHANNELS], axis=-1))
    return {k: np.concatenate(v) for k, v in data.items()}


class StudyMethod:
    """Reference model (ARX per sensor) + base distributions (optionally per command bin) + classifier."""

    def __init__(self, bins: int = 1, order: int = 4) -> None:
        self.bins, self.order = bins, order

    def _regressors(self, w: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        k = self.order
        u, y = w[:, :, 0], w[:, :, c]
        cols = [u[:, k - j:-j] for j in range(1, k + 1)] + [y[:, k - j:-j] for j in range(1, k + 1)]
        phi = np.stack(cols + [np.ones_like(cols[0])], axis=-1)
        return phi, y[:, k:]

    def errors(self, w: np.ndarray) -> np.ndarray:
        """One-step prediction errors (Eq. 5.1) per sensor, (n, W − order, 3)."""
        out = []
        for c in (1, 2, 3):
            phi, y = self._regressors(w, c)
            out.append(y - phi @ self.theta_[c])
        return np.stack(out, axis=-1)

    def _bin(self, w: np.ndarray) -> np.ndarray:
        return np.clip((w[:, :, 0].mean(axis=1) / 4.0 * self.bins).astype(int), 0, self.bins - 1)

    def fit(self, train: dict[str, np.ndarray]) -> StudyMethod:
        healthy = train["healthy"]
        ref = healthy[: max(1, len(healthy) // 5)]
        self.theta_ = {}
        for c in (1, 2, 3):
            phi, y = self._regressors(ref, c)
            self.theta_[c] = np.linalg.lstsq(phi.reshape(-1, phi.shape[-1]), y.reshape(-1), rcond=None)[0]
        self.states_ = list(train)
        base: dict[int, dict[str, np.ndarray]] = {b: {} for b in range(self.bins)}
        clf_windows: dict[str, np.ndarray] = {}
        for s, w in train.items():
            half = len(w) // 2
            e, bins = self.errors(w[:half]), self._bin(w[:half])
            for b in range(self.bins):
                sel = e[bins == b] if np.any(bins == b) else e
                base[b][s] = sel.reshape(-1, 3)
            clf_windows[s] = w[half:]
        self.features_ = {b: RelativeEntropyFeatures(window=W - self.order).fit(base[b]) for b in range(self.bins)}
        X, y = self._features_of(clf_windows)
        self.clf_ = HealthClassifier().fit(X, y, classes=self.states_)
        return self

    def _features(self, w: np.ndarray) -> np.ndarray:
        e, bins = self.errors(w), self._bin(w)
        out = np.empty((len(w), 3 * len(self.states_)))
        for b in range(self.bins):
            sel = bins == b
            if np.any(sel):
                out[sel] = np.stack([self.features_[b].transform(row)[0] for row in e[sel]])
        return out

    def _features_of(self, data: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        X = np.concatenate([self._features(data[s]) for s in data])
        return X, np.repeat(list(data), [len(v) for v in data.values()])

    def predict(self, w: np.ndarray) -> np.ndarray:
        return self.clf_.predict(self._features(w))


def approaches(train: dict[str, np.ndarray], sensors: tuple[str, ...] = ("flow", "speed", "torque"),
               only_parity: bool = False) -> dict[str, object]:
    models: dict[str, object] = {}
    t = time.perf_counter()
    models["parity"] = ConditionModel(features=ConditionFeatures(sensors=sensors)).fit(train)
    fit_s = time.perf_counter() - t
    if not only_parity:
        models["parity-mlp"] = ConditionModel(classifier=HealthClassifier()).fit(train)
        models["study"] = StudyMethod(bins=1).fit(train)
        models["conditioned"] = StudyMethod(bins=4).fit(train)
    print(f"  parity model fit: {fit_s:.1f} s")
    return models


def accuracy(model: object, data: dict[str, np.ndarray], truth: str | None = None, channels: int = 5,
             smoothing: int = 1) -> float:
    """Share of windows read as their state; each label's windows are one machine's (pooled with ``smoothing``)."""
    hits = total = 0
    for state, w in data.items():
        if smoothing == 1:
            pred = model.predict(w[:, :, :channels])  # type: ignore[attr-defined]
        else:
            pred = model.predict(w[:, :, :channels], smoothing=smoothing)  # type: ignore[attr-defined]
        hits += int(np.sum(pred == (truth or state)))
        total += len(w)
    return hits / max(total, 1)


def run(states: tuple[str, ...], train_s: float, test_s: float, quick: bool, parity_only: bool = False) -> None:
    print(f"\n=== {len(states)} states: train {train_s:.0f} s/state, test {test_s:.0f} s/state ===")
    nominal = [state_parameters(s) for s in states]
    labels = list(states)
    train = simulate(nominal, labels, filtered_noise(train_s, (0, 4), seed=1), seed=11)
    models = approaches(train, only_parity=parity_only)
    other_day = [p.replace(Cp=p.Cp * 1.15, Ctm=p.Ctm * 1.15, Cvl=p.Cvl * 1.15, TL=p.TL * 1.03) for p in nominal]
    rng = np.random.default_rng(5)
    spread_labels = labels * 3
    spread = [random_state_parameters(s, rng)[0] for s in spread_labels]
    spread_dc = [random_state_parameters(s, rng)[0] for s in spread_labels]
    warm = {"thermal_drift": {"T_start": 50.0, "T_end": 50.0}}
    conditions = {
        "like training (other seed)": (nominal, labels, filtered_noise(test_s, (0, 4), seed=2), None),
        "other operating day": (other_day, labels, filtered_noise(test_s, (0, 4), seed=3), None),
        "duty cycle 0-4 V": (nominal, labels, duty_cycle(2 * test_s, (0, 4), seed=4), None),
        "slow noise (pole 0.98)": (nominal, labels, filtered_noise(test_s, (0, 4), seed=5, pole=0.98), None),
        "narrow range 1-3 V": (nominal, labels, filtered_noise(test_s, (1, 3), seed=6), None),
        "other range 1-4 V": (nominal, labels, filtered_noise(test_s, (1, 4), seed=7), None),
        "severities spread in bands": (spread, spread_labels, filtered_noise(test_s / 3, (0, 4), seed=8), None),
        "spread in bands, duty cycle": (spread_dc, spread_labels, duty_cycle(2 * test_s / 3, (0, 4), seed=21), None),
        "oil +10 C, noise": (nominal, labels, filtered_noise(test_s, (0, 4), seed=9), warm),
        "oil +10 C, duty cycle": (nominal, labels, duty_cycle(2 * test_s, (0, 4), seed=10), warm),
    }
    names = list(models)
    print(f"  {'condition':30s}" + "".join(f"{n:>13s}" for n in names) + f"{'parity n=6':>13s}{'parity n=12':>13s}")
    for name, (params, labs, u, effects) in conditions.items():
        if quick and name.startswith(("slow", "other range")):
            continue
        data = simulate(params, labs, u, seed=sum(map(ord, name)), effects=effects)
        pooled = "" if len(labs) != len(set(labs)) else "".join(  # pooling needs one machine per label
            f"{100 * accuracy(models['parity'], data, smoothing=n):12.1f}%" for n in (6, 12))
        print(f"  {name:30s}" + "".join(f"{100 * accuracy(models[n], data):12.1f}%" for n in names) + pooled,
              flush=True)
        if effects:  # the same windows without the temperature channel: warm oil cannot be told from leakage
            print(f"  {'  ... no temperature channel':30s}"
                  + "".join(f"{100 * accuracy(models[n], data, channels=4):12.1f}%" for n in names), flush=True)
    smoothing(states, models["parity"], test_s)  # type: ignore[arg-type]
    open_set(states, train, test_s)
    subsets(states, train, test_s)
    timing(models["parity"], train)  # type: ignore[arg-type]


POOLED = (1, 3, 6, 12)
"""Windows pooled per machine in the smoothing rows (1: each window alone)."""


def settled(pred: np.ndarray, n: int) -> np.ndarray:
    """The verdicts of a machine from its n-th window on (its pool full), shape (len(pred) - n + 1,)."""
    return pred[n - 1:]


def confusion(model: ConditionModel, machines: dict[str, np.ndarray], n: int) -> None:
    """Which states are confused, in holds (command range < 0.05 V in the window) or moving, per window or pooled."""
    pairs: dict[tuple[str, str, str], int] = {}
    windows = {"hold": 0, "moving": 0}
    for m, w in machines.items():
        truth = m.split("#")[0]
        part = np.where(np.ptp(w[:, :, 0], axis=1) < 0.05, "hold", "moving")
        for kind in windows:
            windows[kind] += int(np.sum(part == kind))
        for p, kind in zip(model.predict(w, smoothing=n), part):
            if p != truth:
                pairs[(truth, str(p), str(kind))] = pairs.get((truth, str(p), str(kind)), 0) + 1
    errors = {k: sum(c for (_, _, kk), c in pairs.items() if kk == k) for k in windows}
    print(f"  confusion, n={n}: wrong in holds {errors['hold']}/{windows['hold']}, moving "
          f"{errors['moving']}/{windows['moving']} windows; pairs (true -> read, where: windows):", flush=True)
    for (truth, p, kind), c in sorted(pairs.items(), key=lambda kv: -kv[1])[:12]:
        print(f"    {truth:22s} -> {p:22s} {kind:6s} {c}", flush=True)


def smoothing(states: tuple[str, ...], model: ConditionModel, test_s: float) -> None:
    """Duty-cycle accuracy and delay after a change of state with evidence pooled over n windows per machine.

    Delay: a machine reads healthy for 12 windows, then turns into each fault state; counted are
    the windows after the change until the verdict first stops reading healthy (``unknown``
    while the pooled windows mix two states, or a fault) and until it first names the new state.
    Severities spread in their bands: 3 machines per state, on a short duty cycle (all windows,
    the first ones pool fewer) and a long one (also "settled": from each machine's n-th window on).
    """
    params = [state_parameters(s) for s in states]
    duty = simulate(params, list(states), duty_cycle(2 * test_s, (0, 4), seed=4), seed=44)
    rows = {s: model.features_.transform_evidence(w) for s, w in duty.items()}
    layout = model.features_.evidence_layout()
    rng = np.random.default_rng(5)  # severities spread in their bands, one label per machine so each pools alone
    machines = [f"{s}#{i}" for i, s in enumerate(list(states) * 3)]
    spread = simulate([random_state_parameters(m.split("#")[0], rng)[0] for m in machines], machines,
                      duty_cycle(2 * test_s / 3, (0, 4), seed=21), seed=22)
    long = simulate([random_state_parameters(m.split("#")[0], rng)[0] for m in machines], machines,
                    duty_cycle(2 * test_s, (0, 4), seed=23), seed=24)
    for n in POOLED:
        acc = accuracy(model, duty, smoothing=n)
        acc_spread = np.mean(np.concatenate([model.predict(w, smoothing=n) == m.split("#")[0]
                                             for m, w in spread.items()]))
        judged_long = {m: model.predict(w, smoothing=n) == m.split("#")[0] for m, w in long.items()}
        acc_long = np.mean(np.concatenate(list(judged_long.values())))
        acc_settled = np.mean(np.concatenate([settled(v, n) for v in judged_long.values()]))
        noticed, named, named_free = [], [], []  # free: without the operating-point support (SUPPORT_POINTS)
        for s in states[1:]:
            joined = np.concatenate([rows["healthy"][:12], rows[s]])
            points = np.concatenate([operating_points(duty["healthy"][:12]), operating_points(duty[s])])
            verdicts = [v.state for v in model.judge_rows(joined, n, None, layout, points)][12:]
            free = [v.state for v in model.judge_rows(joined, n, None, layout, points, support_points=1)][12:]
            noticed.append(next((i for i, v in enumerate(verdicts) if v != "healthy"), len(verdicts)))
            named.append(next((i for i, v in enumerate(verdicts) if v == s), len(verdicts)))
            named_free.append(next((i for i, v in enumerate(free) if v == s), len(free)))
        print(f"  pooled over {n:2d} windows: duty cycle {100 * acc:5.1f}%; spread in bands {100 * acc_spread:5.1f}% "
              f"(long cycle {100 * acc_long:5.1f}%, settled {100 * acc_settled:5.1f}%); after a change of state, "
              f"not healthy after {np.mean(noticed):.1f} windows (max {max(noticed)}), named after "
              f"{np.mean(named):.1f} (max {max(named)}) windows of 5 s (without the operating-point support "
              f"{np.mean(named_free):.1f}, max {max(named_free)})", flush=True)
    for n in (1, 12):
        confusion(model, long, n)


def open_set(states: tuple[str, ...], train: dict[str, np.ndarray], test_s: float) -> None:
    """Leave each fault out of training in turn; its windows should read unknown (per window and per machine)."""
    faults = sorted({s.rsplit("_", 1)[0] for s in states if s != "healthy"})
    for left_out in faults:
        known = {s: w for s, w in train.items() if not s.startswith(left_out)}
        model = ConditionModel().fit(known)
        unseen = [s for s in states if s.startswith(left_out)]
        u = filtered_noise(test_s, (0, 4), seed=12)
        data = simulate([state_parameters(s) for s in unseen], unseen, u, seed=13)
        held = simulate([state_parameters(s) for s in known], list(known), u, seed=14)
        dc = simulate([state_parameters(s) for s in unseen], unseen, duty_cycle(2 * test_s, seed=15), seed=16)
        held_dc = simulate([state_parameters(s) for s in known], list(known), duty_cycle(2 * test_s, seed=15),
                           seed=17)
        rejected = np.mean(np.concatenate([model.predict(w) == "unknown" for w in data.values()]))
        known_lost = np.mean(np.concatenate([model.predict(w) == "unknown" for w in held.values()]))
        per_n = []
        for n in (1, 6, 12):
            unknown = [model.predict(w, smoothing=n) == "unknown" for w in dc.values()]
            unknown_dc = np.mean(np.concatenate(unknown))
            unknown_settled = np.mean(np.concatenate([settled(v, n) for v in unknown]))
            lost_dc = np.mean(np.concatenate([model.predict(w, smoothing=n) == "unknown" for w in held_dc.values()]))
            per_n.append(f"n={n}: {100 * unknown_dc:.1f}% (settled {100 * unknown_settled:.1f}%, "
                         f"known lost {100 * lost_dc:.2f}%)")
        print(f"  open set, {left_out} never trained: unknown {100 * rejected:.1f}% (noise; known lost "
              f"{100 * known_lost:.2f}%); duty cycle " + ", ".join(per_n), flush=True)


def subsets(states: tuple[str, ...], train: dict[str, np.ndarray], test_s: float) -> None:
    """Accuracy with 1, 2 and 3 sensors (missing ones filled per state), per window and pooled over 6 windows."""
    params = [state_parameters(s) for s in states]
    noise = simulate(params, list(states), filtered_noise(test_s, (0, 4), seed=17), seed=18)
    duty = simulate(params, list(states), duty_cycle(2 * test_s, seed=19), seed=20)
    for sensors in (("flow",), ("speed",), ("torque",), ("flow", "speed"), ("flow", "torque"), ("speed", "torque"),
                    ("flow", "speed", "torque")):
        model = ConditionModel(features=ConditionFeatures(sensors=sensors)).fit(train)
        pooled = accuracy(model, duty, smoothing=6)
        print(f"  sensors {'+'.join(sensors):18s} like training {100 * accuracy(model, noise):5.1f}%   "
              f"duty cycle {100 * accuracy(model, duty):5.1f}%   pooled over 6 {100 * pooled:5.1f}%", flush=True)


def timing(model: ConditionModel, train: dict[str, np.ndarray]) -> None:
    """Scoring cost per window: CPU time of this process with BLAS on one thread (the budget is one core), and wall.

    All three sensors, then two and one (a missing sensor is filled once per distinct fill, up to 5).
    """
    w = np.concatenate(list(train.values()))[:200]
    sparse = {s: ConditionModel(features=ConditionFeatures(sensors=s)).fit(train) for s in (("speed", "torque"),
                                                                                             ("torque",))}
    for sensors, m in ((("flow", "speed", "torque"), model), *sparse.items()):
        m.predict(w[:4])  # compiled kernels loaded
        with threadpool_limits(limits=1):
            t, c = time.perf_counter(), time.process_time()
            m.predict(w)
            wall, cpu = (time.perf_counter() - t) / len(w), (time.process_time() - c) / len(w)
        print(f"  scoring ({'+'.join(sensors)}): {1e3 * cpu:.2f} ms CPU ({1e3 * wall:.2f} ms wall) per window -> "
              f"1000 machines x 1 window per 5 s need {cpu * 1000:.1f} s of one core per 5 s (target <= 5 s; "
              f"ratio {cpu * 1000 / 5:.2f})", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train-seconds", type=float, default=300.0)
    ap.add_argument("--test-seconds", type=float, default=150.0)
    ap.add_argument("--quick", action="store_true", help="skip the slow-noise and other-range rows")
    ap.add_argument("--states", choices=("study", "extended", "both"), default="both")
    ap.add_argument("--parity-only", action="store_true", help="skip the study-method columns")
    args = ap.parse_args()
    if args.states in ("study", "both"):
        run(STUDY_STATES, args.train_seconds, args.test_seconds, args.quick, args.parity_only)
    if args.states in ("extended", "both"):
        run(EXTENDED_STATES, args.train_seconds, args.test_seconds, args.quick, args.parity_only)


if __name__ == "__main__":
    main()
