"""Which component relation breaks, and where: parity-equation localisation (gap-method.md, step 2).

Three relations between the sensors hold when one component behaves as modelled (the component
relations of :mod:`hydrowatch.condition.parity`, integrated over its 40 ms blocks):

- **load** (plant-model.md Eq. 7; study Eq. 2.4): T = JL·ω̇ + BL·ω + TL·tanh(ω/ωs);
- **motor** (Eqs. 6, 8; study Eq. 2.3): Q = N·Dm·ω + Ctm·P̂L + (Vt/4βe)·dP̂L/dt, P̂L from the
  torque balance of the motor shaft;
- **valve** (Eqs. 1–5; study Eqs. 2.1, 2.2, 2.5): Q = Kq·x̂(u)·√(Ps − P̂L) − Cvx·P̂L, the spool and the
  supply line integrated from the command.

Each relation's coefficients are refitted by linear least squares (a gain for the valve), so a
parameter mismatch does not break it; what is left is structure the relation cannot hold. The
reference is what the relation leaves when the nominal structure holds: its residual on a noise-free
simulation of the best model without the effects that touch that relation (the floor:
discretisation, block averaging, on nearly the trajectory the plant followed) plus the
noise-only part, the difference between its residuals on the best model's simulation with and
without white noise at each sensor's noise level (propagated along the trajectory the plant
really followed; the model's own structure cancels, whatever effects it has). A
relation **breaks** when its residual RMS exceeds that reference by BREAK_RATIO; the regime
(command, speed, torque, command direction, acceleration, time) holding most of the excess says
where ("the motor relation breaks at speed < 1.3 rad/s"). A relation that breaks names the
component; all breaking with one sensor in common point at that sensor.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.condition import parity
from hydrowatch.gap.locate import Regime, regimes, strongest_regime
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

RELATIONS: dict[str, str] = {
    "load": "load side (gearbox output, load inertia, damping, friction)",
    "motor": "motor (displacement, leakage, oil compressibility)",
    "valve": "valve and supply (spool, metering, pump and relief)",
}
"""Relation name → the component it checks."""

RELATION_UNITS: dict[str, str] = {"load": "N·m", "motor": "L/min", "valve": "L/min"}

BREAK_RATIO = 1.25
"""A relation breaks when its residual RMS exceeds the noise-only reference by this factor."""

STRUCTURE: dict[str, frozenset[str]] = {
    "load": frozenset({"quadratic_drag", "shaft_compliance", "gear_backlash", "sensor_lowpass"}),
    "motor": frozenset({"entrained_air", "thermal_drift", "stribeck_friction", "shaft_compliance", "gear_backlash",
                        "sensor_lowpass"}),
    "valve": frozenset({"valve_deadband", "valve_saturation", "valve_hysteresis", "transport_delay", "pump_ripple",
                        "thermal_drift", "entrained_air", "stribeck_friction", "shaft_compliance", "gear_backlash",
                        "sensor_lowpass"}),
}
"""Effects that change the structure a relation assumes (the motor and valve relations take P̂L from the
torque balance of a rigid motor shaft and gearbox, so shaft-side effects reach them too)."""

OPERATING_FAMILIES = ("command", "speed", "torque", "command direction", "acceleration", "time")
"""Regime families a break is located in (frequency bands are not, at the block rate)."""


@dataclass(frozen=True)
class RelationCheck:
    """One component relation evaluated on a recording.

    Attributes
    ----------
    name : str
        ``load``, ``motor`` or ``valve``.
    rms, reference_rms : float
        Residual RMS on the measured signals and the noise-only reference, RELATION_UNITS.
    ratio : float
        rms / reference_rms (≈ 1 when the relation holds).
    broken : bool
        ratio > BREAK_RATIO.
    regime : Regime
        Where the excess over the reference lives.
    """

    name: str
    rms: float
    reference_rms: float
    ratio: float
    broken: bool
    regime: Regime

    def as_dict(self) -> dict[str, object]:
        """The report's ``relations`` entry."""
        return {"relation": self.name, "component": RELATIONS[self.name], "ratio": round(self.ratio, 3),
                "broken": self.broken, "regime": self.regime.label, "share": round(self.regime.share, 3),
                "rms": round(self.rms, 6), "reference_rms": round(self.reference_rms, 6),
                "unit": RELATION_UNITS[self.name]}


def _least_squares_residual(y: np.ndarray, columns: list[np.ndarray], mask: np.ndarray) -> np.ndarray:
    """y − Φθ with θ fitted on ``mask`` blocks, shape like y."""
    phi = np.column_stack(columns)
    theta, *_ = np.linalg.lstsq(phi[mask], y[mask], rcond=None)
    return y - phi @ theta


def relation_residuals(voltage: np.ndarray, sensors: np.ndarray, p: PlantParameters, mask: np.ndarray
                       ) -> dict[str, np.ndarray]:
    """Residual of each relation per block after refitting its coefficients.

    Parameters
    ----------
    voltage : ndarray, shape (n,)
        Command, V.
    sensors : ndarray, shape (3, n)
        Flow [L/min], speed [rad/s], torque [N·m].
    p : PlantParameters
        Model whose fixed constants (N, Dm, Jm, Bm, η, ωs, spool, supply) the relations use.
    mask : ndarray of bool, shape (n,)
        Samples the coefficients are fitted on (blocks whose first sample is in it).

    Returns
    -------
    dict of str to ndarray, shape ((n − 1) // parity.BLOCK,)
        ``load`` [N·m], ``motor`` and ``valve`` [L/min].
    """
    flow = sensors[0][None, :] / M3S_TO_LPM
    speed, torque = sensors[1][None, :], sensors[2][None, :]
    blocks = mask[: -1 : parity.BLOCK][: (sensors.shape[1] - 1) // parity.BLOCK]
    pl = parity.load_pressure(speed, torque, p)
    load = _least_squares_residual(
        parity.block_means(torque)[0],
        [parity.block_means(speed)[0], parity.block_rates(speed)[0],
         parity.block_means(np.tanh(speed / p.omega_s))[0]], blocks)
    motor = _least_squares_residual(
        parity.block_means(flow)[0],
        [parity.block_means(speed)[0], parity.block_means(pl)[0], parity.block_rates(pl)[0]], blocks)
    spool = parity.spool_position(voltage[None, :], p)
    predicted = parity.valve_flow_prediction(spool, pl, p, None, np.zeros(1))
    valve = _least_squares_residual(parity.block_means(flow)[0], [parity.block_means(predicted)[0]], blocks)
    return {"load": load, "motor": motor * M3S_TO_LPM, "valve": valve * M3S_TO_LPM}


def check_relations(voltage: np.ndarray, measured: np.ndarray, nominal: Mapping[str, np.ndarray],
                    simulated: np.ndarray, noise: np.ndarray, p: PlantParameters, mask: np.ndarray, seed: int = 0
                    ) -> list[RelationCheck]:
    """Evaluate every relation on the measured sensors against its noise-only reference.

    Parameters
    ----------
    voltage : ndarray, shape (n,)
        Command, V.
    measured : ndarray, shape (3, n)
        Measured flow [L/min], speed [rad/s], torque [N·m].
    nominal : mapping of relation name to ndarray, shape (3, n)
        Per relation, a noise-free simulation in which it holds structurally (the best model
        without the effects of :data:`STRUCTURE` for that relation): the relation's own floor
        (discretisation, block averaging, the smooth friction sign) is what it leaves on that
        trajectory, which should be close to the one the plant followed.
    simulated : ndarray, shape (3, n)
        Noise-free simulation of the best model (with its effects): the trajectory around which the
        noise-only residual is propagated.
    noise : ndarray, shape (3,)
        White sensor-noise standard deviation per sensor (sensor units).
    p : PlantParameters
        Calibrated plant parameters.
    mask : ndarray of bool, shape (n,)
        Samples to use (after the burn-in).
    seed : int, default 0
        Seed of the reference noise.

    Returns
    -------
    list of RelationCheck
        In RELATIONS order.
    """
    rng = np.random.default_rng(seed)
    noisy = simulated + noise[:, None] * rng.standard_normal(simulated.shape)
    found = relation_residuals(voltage, measured, p, mask)
    clean = relation_residuals(voltage, simulated, p, mask)
    floors = {sim.tobytes(): relation_residuals(voltage, sim, p, mask) for sim in nominal.values()}
    floor = {name: floors[nominal[name].tobytes()][name] for name in RELATIONS}
    null = {k: v - clean[k] for k, v in relation_residuals(voltage, noisy, p, mask).items()}
    n_blocks = next(iter(found.values())).size
    blocks = mask[: -1 : parity.BLOCK][:n_blocks]
    u = parity.block_means(voltage[None, :])[0]
    w = parity.block_means(simulated[1][None, :])[0]
    t = parity.block_means(simulated[2][None, :])[0]
    out = []
    for name in RELATIONS:
        r = found[name][blocks]
        ms = float(np.mean(r**2))
        ms0 = float(np.mean(null[name][blocks] ** 2) + np.mean(floor[name][blocks] ** 2)) or 1e-300
        ratio = float(np.sqrt(ms / ms0))
        where = [g for g in regimes(r, u[blocks], w[blocks], t[blocks], ms0, fs=SAMPLE_RATE_HZ / parity.BLOCK)
                 if g.family in OPERATING_FAMILIES]
        out.append(RelationCheck(name, float(np.sqrt(ms)), float(np.sqrt(ms0)), ratio, ratio > BREAK_RATIO,
                                 strongest_regime(where)))
    return out


def describe(checks: list[RelationCheck]) -> str:
    """Plain words: which relations break and where, or that all hold."""
    broken = sorted((c for c in checks if c.broken), key=lambda c: -c.ratio)
    if not broken:
        return "Every component relation (load, motor, valve) holds to within the sensor noise."
    parts = [f"the {c.name} relation breaks (residual ×{c.ratio:.1f} its noise-only level), mostly at "
             f"{c.regime.label} (share {c.regime.share:.2f})" for c in broken]
    held = [c.name for c in checks if not c.broken]
    tail = f"; the {' and '.join(held)} relation{'s' if len(held) > 1 else ''} hold{'' if len(held) > 1 else 's'}" \
        if held else ""
    names = {c.name for c in broken}
    if names == {"motor", "valve"}:
        tail += " (only the relations with the flow sensor break: the flow sensor or the oil between valve and motor)"
    elif names == set(RELATIONS):
        tail += " (all break: the speed or torque sensor, common to all three, or the motor shaft and gearbox)"
    return "Component relations: " + "; ".join(parts) + tail + "."
