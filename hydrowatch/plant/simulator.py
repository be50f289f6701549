"""Streaming, batched simulator of the hydrostatic transmission (plant-model.md).

:class:`PlantSimulator` advances M machines in chunks of samples and keeps their state between
calls (river-style streaming: constant memory, chunked == one long run, bit for bit).
:func:`simulate` runs one machine over a whole command and returns a :class:`Recording`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.plant.dynamics import N_COEF, N_LOAD, N_ODE, PS, TEMP, coefficients, rates
from hydrowatch.plant.effects import (
    EFFECTS,
    REFERENCE_TEMPERATURE_C,
    Effects,
    effect_row,
    resolve_effects,
)
from hydrowatch.plant.kernel import CHANNELS_OUT, COUNT, N_SENSORS, state_width
from hydrowatch.plant.kernel import advance as _advance
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ, Recording

_OUT_NAMES = PLANT.measured
"""Names of the kernel's output columns (:meth:`hydrowatch.channels.ChannelSet.column`)."""
CHANNELS: tuple[str, ...] = tuple(c for c in _OUT_NAMES if c != "temperature")
"""Sensor channels of :meth:`PlantSimulator.step` (``temperature`` [°C] comes as well, always)."""

DEFAULT_SUBSTEPS = 10
"""RK4 steps per 200 Hz sample (2 kHz); agrees with RK4 at 10 kHz to < 1e-3 relative (docs/plant.md)."""
REFERENCE_SUBSTEPS = 50
"""RK4 steps per 200 Hz sample of the reference integrator (10 kHz, plant-model.md)."""


def zero_flow_supply_pressure(parameters: PlantParameters, leak_factor: float = 1.0) -> float:
    """Supply pressure with the valve closed and the pump at its mean flow, Pa (Eqs. 1, 2, 5 at rest).

    Solves Dp·ωp − (Cp + Cpl + Cvl)·f·Ps − Kr·max(0, Ps − Pc) = 0, f the thermal leakage factor.
    """
    q = parameters.Dp * parameters.omega_p
    leak = (parameters.Cp + parameters.Cpl + parameters.Cvl) * leak_factor
    if leak * parameters.Pc >= q:
        return q / leak
    return (q + parameters.Kr * parameters.Pc) / (parameters.Kr + leak)


class PlantSimulator:
    """Streaming simulator of M machines that keeps its state between :meth:`step` calls.

    Parameters
    ----------
    parameters : PlantParameters or sequence of PlantParameters
        One per machine; M = its length (1 for a single object).
    effects : mapping, sequence of (mapping or None), or None
        Effects switched on (``{id: {param: value}}``, see :mod:`hydrowatch.plant.effects`): one
        mapping for every machine, or one entry per machine. Default: the nominal model.
    noise : bool, default True
        Add white Gaussian sensor noise (standard deviations from the parameters).
    seed : int, sequence of int, or None
        Noise seed. One int for M = 1 seeds ``Generator(PCG64(seed))``; for M > 1 one int is split
        into M independent streams (``SeedSequence(seed).spawn(M)``); a sequence gives each machine
        its own. None draws a fresh seed, kept in :attr:`seed` so the run can be repeated.
    sample_rate : float, default 200.0
        Samples per second, Hz.
    t0 : float, default 0.0
        Time of the first sample, s.
    substeps : int, default DEFAULT_SUBSTEPS
        RK4 steps per sample interval (50 at 200 Hz is the 10 kHz reference integrator).

    Notes
    -----
    Initial state: at rest (x = 0, PL = 0, ωm = 0), Ps at its zero-flow steady value, oil at
    40 °C (or thermal_drift's ``T_start``), delay line and play operator at 0 V.
    """

    def __init__(
        self,
        parameters: PlantParameters | Sequence[PlantParameters],
        effects: Effects | Sequence[Effects | None] | None = None,
        *,
        noise: bool = True,
        seed: int | Sequence[int] | None = None,
        sample_rate: float = SAMPLE_RATE_HZ,
        t0: float = 0.0,
        substeps: int = DEFAULT_SUBSTEPS,
    ) -> None:
        machines = [parameters] if isinstance(parameters, PlantParameters) else list(parameters)
        if not machines or not all(isinstance(p, PlantParameters) for p in machines):
            raise ParameterError(
                "parameters must be a PlantParameters or a non-empty sequence of them. "
                f"Got {type(parameters).__name__}."
            )
        self.n_machines = len(machines)
        if effects is None or isinstance(effects, Mapping):
            per_machine: list[Effects | None] = [effects] * self.n_machines
        else:
            per_machine = list(effects)
            if len(per_machine) != self.n_machines:
                raise ParameterError(
                    f"effects must have one entry per machine ({self.n_machines}). Got {len(per_machine)}."
                )
        if not (np.isfinite(sample_rate) and sample_rate > 0):
            raise ParameterError(f"sample_rate must be a positive number of Hz. Got {sample_rate!r}.")
        if int(substeps) != substeps or substeps < 1:
            raise ParameterError(f"substeps must be a positive integer. Got {substeps!r}.")
        self.noise = bool(noise)
        self.sample_rate = float(sample_rate)
        self.t0 = float(t0)
        self.substeps = int(substeps)
        self.effects = [resolve_effects(e) for e in per_machine]
        self.parameters = machines
        self.seed = _resolve_seed(seed, self.n_machines)
        self._params = np.stack([p.as_array() for p in machines])
        self._effects = np.stack([effect_row(e) for e in self.effects])
        upper_delay = EFFECTS["transport_delay"].parameters["tau"][4]
        self._ring = int(np.ceil(upper_delay * self.sample_rate)) + 2
        self.reset()

    # -- streaming -------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the initial state at t0, noise streams restarted from the seed."""
        self._state = np.zeros((self.n_machines, state_width(self._ring)))
        for m, (params, effects) in enumerate(zip(self.parameters, self.effects)):
            thermal = effects.get("thermal_drift")
            temperature = thermal["T_start"] if thermal else REFERENCE_TEMPERATURE_C
            factor = np.exp(thermal["k_visc"] * (temperature - REFERENCE_TEMPERATURE_C)) if thermal else 1.0
            self._state[m, PS] = zero_flow_supply_pressure(params, float(factor))
            self._state[m, TEMP] = temperature
        self._rngs = _generators(self.seed, self.n_machines)

    @property
    def state(self) -> np.ndarray:
        """Copy of the internal state, shape (M, S) (layout in :mod:`hydrowatch.plant.kernel`)."""
        return self._state.copy()

    @property
    def time(self) -> float:
        """Time of the next sample, s."""
        return self.t0 + float(self._state[0, COUNT]) / self.sample_rate

    def step(self, voltage: np.ndarray) -> dict[str, np.ndarray]:
        """Advance by n samples with the given valve command.

        Parameters
        ----------
        voltage : array_like, shape (n,) or (M, n)
            Valve command, V, held over each sample interval. A 1-D command drives every machine.

        Returns
        -------
        dict of str to ndarray
            ``t`` [s], ``voltage`` [V], ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m],
            ``supply_pressure``, ``load_pressure`` [bar], ``temperature`` [°C]; shape (n,) for one
            machine given a 1-D command, else (M, n). Sample k is read at t_k, before u[k] acts.
        """
        command = self._command(voltage)
        n = command.shape[1]
        if self.noise:
            draws = np.empty((self.n_machines, n, N_SENSORS))
            for m, rng in enumerate(self._rngs):
                draws[m] = rng.standard_normal((n, N_SENSORS))
        else:
            draws = np.empty((0, 0, N_SENSORS))
        out = np.empty((self.n_machines, n, CHANNELS_OUT))
        t = self.t0 + (self._state[0, COUNT] + np.arange(n)) / self.sample_rate
        _advance(self._params, self._effects, self._state, command, draws, out, self.sample_rate, self.t0,
                 self.substeps, True)
        result = {"t": np.broadcast_to(t, (self.n_machines, n)).copy(), "voltage": command}
        result.update({name: out[:, :, c] for c, name in enumerate(_OUT_NAMES)})
        if np.ndim(voltage) == 1 and self.n_machines == 1:
            return {k: v[0] for k, v in result.items()}
        return result

    def set_parameters(self, index: int, parameters: PlantParameters) -> None:
        """Change machine ``index``'s parameters from the next sample on (degradation paths)."""
        if not isinstance(parameters, PlantParameters):
            raise ParameterError(f"parameters must be a PlantParameters. Got {type(parameters).__name__}.")
        if not -self.n_machines <= index < self.n_machines:
            raise ParameterError(f"machine index must be in [0, {self.n_machines}). Got {index}.")
        self.parameters[index] = parameters
        self._params[index] = parameters.as_array()

    def settle(self, voltage: float | np.ndarray, seconds: float = 3.0) -> None:
        """Run at a constant command until steady, without advancing t, temperature, noise or output.

        Parameters
        ----------
        voltage : float or array_like, shape (M,)
            Constant command, V, for all machines or per machine.
        seconds : float, default 3.0
            How long to run, s (a few times the slowest time constant of the nominal plant).
        """
        level = np.broadcast_to(np.asarray(voltage, dtype=np.float64), (self.n_machines,))
        if not (np.isfinite(seconds) and seconds >= 0):
            raise ParameterError(f"settle seconds must be finite and >= 0. Got {seconds!r}.")
        n = int(round(seconds * self.sample_rate))
        command = self._command(np.repeat(level[:, None], n, axis=1))
        out = np.empty((self.n_machines, n, CHANNELS_OUT))
        _advance(self._params, self._effects, self._state, command, np.empty((0, 0, N_SENSORS)), out, self.sample_rate,
                 self.t0, self.substeps, False)

    def _command(self, voltage: np.ndarray) -> np.ndarray:
        command = np.asarray(voltage, dtype=np.float64)
        if command.ndim == 1:
            command = np.broadcast_to(command, (self.n_machines, command.shape[0]))
        if command.ndim != 2 or command.shape[0] != self.n_machines:
            raise DataError(
                f"voltage must have shape (n,) or ({self.n_machines}, n). Got {np.shape(voltage)}."
            )
        if not np.all(np.isfinite(command)):
            raise DataError("voltage must be finite. Got NaN or inf. Fill or drop the bad samples.")
        return np.ascontiguousarray(command)


def _resolve_seed(seed: int | Sequence[int] | None, n_machines: int) -> int | list[int]:
    if seed is None:
        entropy = int(np.random.SeedSequence().entropy)  # type: ignore[arg-type]
        return entropy % (2**63)
    if isinstance(seed, (int, np.integer)):
        return int(seed)
    seeds = [int(s) for s in seed]
    if len(seeds) != n_machines:
        raise ParameterError(f"seed must be one int or one per machine ({n_machines}). Got {len(seeds)}.")
    return seeds


def _generators(seed: int | list[int], n_machines: int) -> list[np.random.Generator]:
    if isinstance(seed, list):
        return [np.random.Generator(np.random.PCG64(s)) for s in seed]
    if n_machines == 1:
        return [np.random.Generator(np.random.PCG64(seed))]
    return [np.random.Generator(np.random.PCG64(child)) for child in np.random.SeedSequence(seed).spawn(n_machines)]


def simulate(
    voltage: np.ndarray,
    parameters: PlantParameters | None = None,
    effects: Effects | None = None,
    *,
    noise: bool = True,
    seed: int | None = None,
    settle: bool = True,
    meta: dict[str, Any] | None = None,
) -> Recording:
    """Simulate one machine over a whole command at 200 Hz.

    Parameters
    ----------
    voltage : array_like, shape (n,)
        Valve command, V.
    parameters : PlantParameters, optional
        Default: nominal.
    effects : mapping, optional
        Effects switched on (see :mod:`hydrowatch.plant.effects`).
    noise : bool, default True
        Add sensor noise.
    seed : int, optional
        Noise seed; None draws one (recorded in ``meta["seed"]``).
    settle : bool, default True
        Start from the steady state at ``voltage[0]`` instead of rest.
    meta : dict, optional
        Extra metadata (fleet, machine, state, ...), copied into the recording.

    Returns
    -------
    Recording
        Channels voltage, flow, speed, torque, supply_pressure, load_pressure, temperature; meta
        with ``parameters``, ``effects``, ``seed``, ``noise``, ``settled``.
    """
    command = np.asarray(voltage, dtype=np.float64)
    if command.ndim != 1 or command.size == 0:
        raise DataError(f"voltage must be a non-empty 1-D array. Got shape {command.shape}.")
    params = parameters if parameters is not None else PlantParameters()
    sim = PlantSimulator(params, effects, noise=noise, seed=seed)
    if settle:
        sim.settle(float(command[0]))
    out = sim.step(command)
    info = dict(meta or {})
    info.update(parameters=params.to_dict(), effects=sim.effects[0], seed=sim.seed, noise=noise, settled=settle)
    return Recording(out["t"], {name: out[name] for name in PLANT.names}, info)


def linear_modes(
    voltage: float, parameters: PlantParameters | None = None, effects: Effects | None = None, *, seconds: float = 5.0
) -> tuple[np.ndarray, np.ndarray]:
    """Oscillatory modes of the plant linearised at the steady state of a constant command.

    The state is settled for ``seconds`` at ``voltage`` (noise off), then the Jacobian of the
    right-hand side (Eqs. 3–7 with the effects) is taken by central differences.

    Returns
    -------
    frequency : ndarray, shape (k,)
        Undamped natural frequencies |λ|/2π of the complex pole pairs, Hz, ascending.
    damping : ndarray, shape (k,)
        Their damping ratios.
    """
    sim = PlantSimulator(parameters or PlantParameters(), effects, noise=False)
    sim.settle(voltage, seconds)
    y0 = sim._state[0, :N_ODE].copy()
    coef = np.empty(N_COEF + N_LOAD)
    coefficients(sim._params[0], coef)
    row, ds, sensors = sim._effects[0], np.empty(N_ODE), np.empty(N_SENSORS)
    scale = np.maximum(np.abs(y0), 1.0) * 1e-6
    jac = np.zeros((N_ODE, N_ODE))
    for j in range(N_ODE):
        for sign in (1.0, -1.0):
            y = y0.copy()
            y[j] += sign * scale[j]
            rates(coef, row, y, float(voltage), 0.0, False, ds, sensors)
            jac[:, j] += sign * ds / (2.0 * scale[j])
    poles = np.linalg.eigvals(jac)
    poles = poles[poles.imag > 1e-6]
    poles = poles[np.argsort(np.abs(poles))]
    return np.abs(poles) / (2.0 * np.pi), -poles.real / np.abs(poles)
