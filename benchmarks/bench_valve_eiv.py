"""Why a worn relief spring reads as a weak valve coil: the torque noise in the valve relation (issue 11, 13 states).

On a 0.5–3.5 V duty cycle the relief_spring and valve_coil hypotheses of the valve relation (Eqs. 1–5) explain each
other's machines almost equally; what tips them is the load pressure P̂L taken from the torque transducer. A weaker
relief spring lowers Ps − P̂L, so its predicted flow follows P̂L's noise more steeply (∂Q̂/∂P̂L ∝ 1/√(Ps − P̂L)) than a
weaker coil's at the same flow: errors in variables add (∂Q̂/∂P̂L)²·σ_PL² to a hypothesis' MSE and favour the coil.

For units of a population (``bench_unseen_units.py``'s draws: the unit identified from 300 s of its own healthy
filtered noise, its later day's machines at spread severities on the duty cycle), this prints, per machine, the mean
over windows of log MSE(relief_spring) − log MSE(valve_coil) at each hypothesis' fitted severity (negative: the relief
explains the window better):

- ``raw``: the relation as the health features use it;
- ``noise-free``: the same machines simulated without torque noise;
- ``corrected``: each MSE less its expected errors-in-variables share mean_b (∂Q̂/∂P̂L)_b²·σ_PL²·w (w = 7.5/64 for the
  trapezoid block mean of :data:`hydrowatch.condition.parity.BLOCK` samples; σ_PL = σ_T/(N·η·Dm) with the
  simulated σ_T: an oracle, to show what a measured noise level would buy).

Run: ``python benchmarks/bench_valve_eiv.py [--seed 2039] [--units 11]`` (1-based unit numbers, comma-separated;
about 40 s per unit on one core).
"""

from __future__ import annotations

import argparse

import numpy as np
from bench_unseen_units import simulate, unit_conditions
from threadpoolctl import threadpool_limits

from hydrowatch.condition import parity
from hydrowatch.condition.estimates import parity_estimates, window_signals
from hydrowatch.condition.unit import identify_unit
from hydrowatch.plant import PlantParameters
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.faults import EXTENDED_STATES
from hydrowatch.plant.population import later_day, random_unit

MACHINES = ("relief_spring_warning", "valve_coil_warning", "relief_spring_alert", "valve_coil_alert")
BLOCK_WEIGHT = (0.25 + 0.25 + (parity.BLOCK - 1)) / parity.BLOCK**2
"""Variance of a trapezoid block mean of white noise over the per-sample variance."""


def log_mse_difference(windows: np.ndarray, p: PlantParameters, sigma_pl: float) -> tuple[float, float]:
    """Mean over windows of log MSE(relief_spring) − log MSE(valve_coil): raw, and less the errors-in-variables share
    of each hypothesis for load-pressure noise ``sigma_pl`` (Pa)."""
    sig = window_signals(windows, ("flow", "speed", "torque"), p)
    est = parity_estimates(sig, p)
    raw, corrected = {}, {}
    for h in ("relief_spring", "valve_coil"):
        s = est.severity[h]
        r = parity.valve_residual(sig.flow, sig.spool, sig.load_pressure, p, h, s, sig.leak)
        q0 = parity.valve_flow_prediction(sig.spool, sig.load_pressure, p, h, s, sig.leak)
        q1 = parity.valve_flow_prediction(sig.spool, sig.load_pressure + 1e4, p, h, s, sig.leak)
        slope = parity.block_means((q1 - q0) / 1e4 * parity.M3S_TO_LPM)  # L/min per Pa
        mse = np.mean(r**2, axis=1)
        raw[h] = np.log(mse)
        corrected[h] = np.log(np.maximum(mse - np.mean(slope**2, axis=1) * sigma_pl**2 * BLOCK_WEIGHT, 1e-12))
    return (float(np.mean(raw["relief_spring"] - raw["valve_coil"])),
            float(np.mean(corrected["relief_spring"] - corrected["valve_coil"])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2039, help="population seed of bench_unseen_units.py")
    ap.add_argument("--units", default="11", help="1-based unit numbers, comma-separated")
    args = ap.parse_args()
    wanted = sorted(int(u) for u in args.units.split(","))
    rng = np.random.default_rng(args.seed)
    units = []
    for _ in range(wanted[-1]):
        unit = random_unit(rng)
        units.append((unit, later_day(unit, rng)))
    print("| unit | machine | raw | noise-free | corrected (oracle σ_T) |\n|---|---|---|---|---|")
    with threadpool_limits(1):
        for number in wanted:
            unit, day = units[number - 1]
            seed = 1000 * number + args.seed
            healthy = simulate([unit], filtered_noise(300.0, (0, 4), seed=seed), seed)[0][:, :, :4]
            p = identify_unit(healthy).parameters
            spread = next(c for c in unit_conditions(day, EXTENDED_STATES, np.random.default_rng(seed), 100.0, seed)
                          if c[0] == "spread, duty cycle")
            _, params, command, effects, _ = spread
            noisy = simulate(params, command, seed + 100, effects)
            quiet = simulate([q.replace(noise_torque=0.0) for q in params], command, seed + 100, effects)
            sigma_pl = day.noise_torque / (p.N * p.eta * p.Dm)
            for state in MACHINES:
                k = EXTENDED_STATES.index(state)
                raw, corrected = log_mse_difference(noisy[k][:, :, :4], p, sigma_pl)
                free, _ = log_mse_difference(quiet[k][:, :, :4], p, 0.0)
                print(f"| {number} | {state} | {raw:+.3f} | {free:+.3f} | {corrected:+.3f} |", flush=True)


if __name__ == "__main__":
    main()
