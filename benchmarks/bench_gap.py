"""Success rates and cost of the gap analyser (issue 6).

For every effect: recordings made by the simulator with the effect concealed at a random realistic
magnitude, on a plant whose calibrated parameters differ from nominal by ±20 %, with sensor noise,
a 0–4 V filtered-noise command (bipolar −4…4 V for gear_backlash). The analysis starts from the
nominal parameters. A run is *right* when the report names the effect first and the held-out
NRMSE of the first located sensor falls by >= 30 % from the calibrated fit. The null case (no
effect) is right when ``mismatch`` is false. Pairs are right when both effects are named.

Targets: >= 90 % right per effect, no false discovery in the null case, a 120 s recording in under
5 minutes on 2 cores (reference = 300 s; the ratio is printed).

    python benchmarks/bench_gap.py --seeds 5 --seconds 30
    python benchmarks/bench_gap.py --effects none,transport_delay --seeds 10
    python benchmarks/bench_gap.py --timing 120          # one 120 s recording, all candidates

Timings on a shared machine are pessimistic: say how loaded it was.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.gap import CALIBRATED, GapAnalyser
from hydrowatch.plant.effects import EFFECT_IDS
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

MAGNITUDES: dict[str, dict[str, tuple[float, float]]] = {
    "stribeck_friction": {"Ts": (0.6, 1.5), "Tc": (0.1, 0.3)},
    "quadratic_drag": {"Kd": (0.02, 0.05)},
    "valve_deadband": {"d": (0.05, 0.15)},
    "valve_saturation": {"x_max": (0.45, 0.65)},
    "valve_hysteresis": {"r": (0.1, 0.3)},
    "transport_delay": {"tau": (0.005, 0.02)},
    "entrained_air": {"alpha": (0.02, 0.1)},
    "pump_ripple": {"a1": (0.05, 0.2), "a2": (0.02, 0.1)},
    "thermal_drift": {"T_start": (30.0, 40.0), "T_end": (60.0, 80.0), "tau": (60.0, 300.0)},
    "gear_backlash": {"b": (0.01, 0.04)},
    "shaft_compliance": {"G": (300.0, 1500.0)},
    "sensor_lowpass": {"sensor": (0.0, 2.0), "tau": (0.01, 0.05)},
}
"""Ranges of the concealed magnitudes (uniform); sensor_lowpass's sensor is drawn from {0, 1, 2}."""

REFERENCE_SECONDS = 300.0
"""Target wall time for a 120 s recording, s."""


def draw_effect(effect_id: str, rng: np.random.Generator) -> dict[str, float]:
    """A random realistic magnitude of one effect."""
    values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in MAGNITUDES[effect_id].items()}
    if effect_id == "sensor_lowpass":
        values["sensor"] = float(rng.integers(0, 3))
    return values


def plant(rng: np.random.Generator, spread: float = 0.2) -> PlantParameters:
    """Nominal plant with every calibrated parameter scaled by U(1 − spread, 1 + spread)."""
    p = PlantParameters()
    return p.replace(**{k: getattr(p, k) * rng.uniform(1 - spread, 1 + spread) for k in CALIBRATED})


def one_run(effect_ids: tuple[str, ...], seed: int, seconds: float, candidates: tuple[str, ...] | None
            ) -> tuple[bool, float, dict]:
    """Simulate, analyse, judge. Returns (right, wall seconds, report)."""
    rng = np.random.default_rng(seed)
    effects = {e: draw_effect(e, rng) for e in effect_ids}
    volts = (-4.0, 4.0) if "gear_backlash" in effect_ids else (0.0, 4.0)
    rec = simulate(filtered_noise(seconds, volts, seed=seed), plant(rng), effects, seed=seed)
    start = time.perf_counter()
    report = GapAnalyser(candidates=candidates).fit(rec).report_
    wall = time.perf_counter() - start
    named = [e["id"] for e in report["effects"]]
    if not effect_ids:
        return report["mismatch"] is False, wall, report
    if len(effect_ids) > 1:
        return set(effect_ids) <= set(named), wall, report
    if not named or named[0] != effect_ids[0] or not report["located"]:
        return False, wall, report
    sensor = report["located"][0]["sensor"]
    cut = 1 - report["fit"]["after"][sensor] / report["fit"]["calibrated"][sensor]
    return cut >= 0.3, wall, report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default="none," + ",".join(EFFECT_IDS),
                        help="comma list; 'none' is the null case; 'a+b' is a pair")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--candidates", help="comma list of candidate effects (default: all)")
    parser.add_argument("--timing", type=float, help="only time one recording of this many seconds (null case)")
    args = parser.parse_args()
    candidates = tuple(args.candidates.split(",")) if args.candidates else None
    if args.timing:
        _, wall, report = one_run(("transport_delay",), 0, args.timing, candidates)
        print(f"{args.timing:g} s recording, transport_delay concealed: {wall:.1f} s wall "
              f"(reference {REFERENCE_SECONDS:g} s, ratio {wall / REFERENCE_SECONDS:.2f}); named "
              f"{[e['id'] for e in report['effects']]}")
        return
    print(f"{'case':40s} {'right':>7s} {'rate':>6s} {'mean s':>7s}  named (first seed)")
    for case in args.effects.split(","):
        ids = () if case == "none" else tuple(case.split("+"))
        results = [one_run(ids, seed, args.seconds, candidates) for seed in range(args.seeds)]
        right = sum(r[0] for r in results)
        wall = float(np.mean([r[1] for r in results]))
        named = [[e["id"] for e in r[2]["effects"]] for r in results]
        print(f"{case:40s} {right:3d}/{len(results):<3d} {right / len(results):6.0%} {wall:7.1f}  {named}",
              flush=True)


if __name__ == "__main__":
    main()
