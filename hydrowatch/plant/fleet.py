"""A fleet: N machines simulated together, each with its own parameters, health state and effects.

Each machine has a healthy parameter set (the nominal one, optionally scattered by a few percent
as manufacturing spread), a fixed health state or a :class:`~hydrowatch.plant.wear.DegradationPath` (a fault whose speed
drop at 2 V grows, linearly or accelerating, over minutes to hours, so a fleet shows faults appearing),
and its own effects.
All machines advance together in one :class:`~hydrowatch.plant.simulator.PlantSimulator`.
Degradation is applied every ``update_seconds`` of simulated time (parameters change between
samples, never inside one); labels follow the nearest named level of the current speed drop
(:func:`hydrowatch.plant.faults.level_for_speed_drop`).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.plant.effects import Effects
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.faults import LEVELS, level_severity, parse_state, speed_drop_table, state_parameters
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import PlantSimulator, simulate
from hydrowatch.plant.wear import EXP_GROWTH, SHAPES, DegradationPath, Wear, path_state, worn_parameters
from hydrowatch.recording import SAMPLE_RATE_HZ, Recording

__all__ = [  # the paths and Wear live in hydrowatch.plant.wear; importable from here as before
    "EXP_GROWTH",
    "SCATTERED_PARAMETERS",
    "SHAPES",
    "DegradationPath",
    "Fleet",
    "MachineSpec",
    "Wear",
    "path_state",
    "scatter_parameters",
    "simulate_states",
    "state_seeds",
    "worn_parameters",
]

SCATTERED_PARAMETERS: tuple[str, ...] = (
    "Dp", "Cp", "Pc", "Kr", "beta_e", "Kq", "omega_v", "zeta_v", "Kc", "Cvl", "Dm", "Ctm", "Jm", "Bm",
    "JL", "BL", "TL",
)
"""Parameters that differ between machines of one build (manufacturing spread)."""

def scatter_parameters(nominal: PlantParameters, spread: float, rng: np.random.Generator) -> PlantParameters:
    """A machine of the same build: each of :data:`SCATTERED_PARAMETERS` times U(1 − spread, 1 + spread).

    Parameters
    ----------
    nominal : PlantParameters
        The design values.
    spread : float
        Relative half-width in [0, 0.5), e.g. 0.03 for ±3 %.
    rng : numpy.random.Generator
        Source of the factors.
    """
    if not (np.isfinite(spread) and 0.0 <= spread < 0.5):
        raise ParameterError(f"parameter scatter must be a fraction in [0, 0.5). Got {spread!r}. Give e.g. 0.03.")
    factors = rng.uniform(1.0 - spread, 1.0 + spread, len(SCATTERED_PARAMETERS))
    return nominal.replace(**{name: getattr(nominal, name) * f for name, f in zip(SCATTERED_PARAMETERS, factors)})


@dataclass(frozen=True)
class MachineSpec:
    """One machine of a fleet.

    Attributes
    ----------
    machine : str
        Machine id (free-form, no ``/``).
    state : str, default "healthy"
        Fixed health state; ignored when ``path`` is given.
    path : DegradationPath, optional
        A fault developing over time.
    effects : mapping, optional
        Effects switched on for this machine (see :mod:`hydrowatch.plant.effects`).
    seed : int, optional
        This machine's noise seed; default: derived from the fleet's seed.
    """

    machine: str
    state: str = "healthy"
    path: DegradationPath | None = None
    effects: Effects | None = None
    seed: int | None = None

    def __post_init__(self) -> None:
        if not self.machine or "/" in self.machine:
            raise ParameterError(f"machine id must be non-empty without '/'. Got {self.machine!r}.")
        parse_state(self.state)


class Fleet:
    """N machines simulated together in real time or faster (streaming, like the simulator).

    Parameters
    ----------
    machines : int or sequence of MachineSpec
        An int n makes n healthy machines ``m00``, ``m01``, …
    fleet : str, default "fleet"
        Fleet id (recording metadata, bus keys).
    nominal : PlantParameters, optional
        Design parameters of every machine (default nominal).
    scatter : float, default 0.0
        Manufacturing spread of each machine's healthy parameters, relative half-width (e.g. 0.03).
    noise : bool, default True
        Sensor noise.
    seed : int, optional
        Seeds the scatter and every machine's noise stream (None: fresh, kept in :attr:`seed`).
    update_seconds : float, default 1.0
        How often degradation paths move the parameters, s of fleet time.
    t0 : float, default 0.0
        Time of the first sample, s.
    substeps : int, optional
        RK4 steps per sample (the simulator's default when None).
    """

    def __init__(
        self,
        machines: int | Sequence[MachineSpec],
        *,
        fleet: str = "fleet",
        nominal: PlantParameters | None = None,
        scatter: float = 0.0,
        noise: bool = True,
        seed: int | None = None,
        update_seconds: float = 1.0,
        t0: float = 0.0,
        substeps: int | None = None,
    ) -> None:
        specs = [MachineSpec(f"m{i:02d}") for i in range(machines)] if isinstance(machines, int) else list(machines)
        if not specs:
            raise ParameterError("a fleet must have at least one machine. Got none.")
        ids = [s.machine for s in specs]
        if len(set(ids)) != len(ids):
            raise ParameterError(f"machine ids must be unique. Got {ids}.")
        if not (np.isfinite(update_seconds) and update_seconds > 0):
            raise ParameterError(f"update_seconds must be positive. Got {update_seconds!r}.")
        self.fleet = fleet
        self.specs = specs
        self.seed = int(np.random.default_rng().integers(2**63)) if seed is None else int(seed)
        scatter_seq, noise_seq = np.random.SeedSequence(self.seed).spawn(2)
        design = nominal if nominal is not None else PlantParameters()
        rng = np.random.default_rng(scatter_seq)
        self.healthy = [scatter_parameters(design, scatter, rng) if scatter else design for _ in specs]
        """Each machine's healthy parameters (after scatter)."""
        self._tables = [
            speed_drop_table(s.path.fault, s.path.top_drop, h) if s.path is not None else None
            for s, h in zip(specs, self.healthy)
        ]
        self._drops = np.zeros(len(specs))
        params = [self._parameters_at(i, t0) for i in range(len(specs))]
        kwargs: dict[str, Any] = {} if substeps is None else {"substeps": substeps}
        noise_seeds = [int(c.generate_state(1)[0]) if s.seed is None else s.seed
                       for s, c in zip(specs, noise_seq.spawn(len(specs)))]
        self.simulator = PlantSimulator(params, [s.effects for s in specs], noise=noise, seed=noise_seeds,
                                        t0=t0, **kwargs)
        self._update_samples = max(1, int(round(update_seconds * SAMPLE_RATE_HZ)))
        self._samples = 0

    @property
    def n_machines(self) -> int:
        """Number of machines M."""
        return len(self.specs)

    @property
    def machine_ids(self) -> list[str]:
        """Machine ids in simulator order."""
        return [s.machine for s in self.specs]

    @property
    def time(self) -> float:
        """Time of the next sample, s."""
        return self.simulator.time

    @property
    def drops(self) -> np.ndarray:
        """Current speed drop at 2 V of each machine's fault, shape (M,), fraction (0 = healthy)."""
        return self._drops.copy()

    @property
    def states(self) -> list[str]:
        """Current health label of each machine (fixed state, or the nearest level of its path)."""
        labels = []
        for spec, drop in zip(self.specs, self._drops):
            labels.append(spec.state if spec.path is None else path_state(spec.path, float(drop)))
        return labels

    def _parameters_at(self, index: int, t: float) -> PlantParameters:
        spec, healthy, table = self.specs[index], self.healthy[index], self._tables[index]
        if spec.path is None or table is None:
            _, level = parse_state(spec.state)
            self._drops[index] = 0.0 if level is None else LEVELS[level]
            return state_parameters(spec.state, healthy)
        parameters, self._drops[index] = worn_parameters(spec.path, healthy, table, t)
        return parameters

    def settle(self, voltage: float = 0.0, seconds: float = 3.0) -> None:
        """Bring every machine to rest at a constant command without advancing time (see the simulator)."""
        self.simulator.settle(voltage, seconds)

    def step(self, voltage: np.ndarray) -> dict[str, np.ndarray]:
        """Advance every machine by n samples; degradation moves parameters every ``update_seconds``.

        Parameters
        ----------
        voltage : array_like, shape (n,) or (M, n)
            Valve command, V: one for all machines or one row per machine.

        Returns
        -------
        dict of str to ndarray, shape (M, n)
            ``t`` [s], ``voltage`` [V], ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m],
            ``supply_pressure``, ``load_pressure`` [bar], ``temperature`` [°C].
        """
        command = np.asarray(voltage, dtype=np.float64)
        if command.ndim == 1:
            command = np.broadcast_to(command, (self.n_machines, command.shape[0]))
        n = command.shape[1]
        if n == 0 or not any(s.path is not None for s in self.specs):
            self._samples += n
            return self._as_fleet(self.simulator.step(command))
        parts, start = [], 0
        while start < n:  # parameters move on a fixed grid of fleet time, whatever the chunk sizes
            phase = self._samples % self._update_samples
            if phase == 0:
                for i, spec in enumerate(self.specs):
                    if spec.path is not None:
                        self.simulator.set_parameters(i, self._parameters_at(i, self.time))
            take = min(n - start, self._update_samples - phase)
            parts.append(self._as_fleet(self.simulator.step(command[:, start:start + take])))
            start += take
            self._samples += take
        return {k: np.concatenate([p[k] for p in parts], axis=1) for k in parts[0]}

    def _as_fleet(self, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: v if v.ndim == 2 else v[None, :] for k, v in out.items()}

    def recordings(self, out: dict[str, np.ndarray]) -> list[Recording]:
        """Split a :meth:`step` result into one :class:`Recording` per machine, labelled.

        ``meta`` holds ``fleet``, ``machine``, ``state`` (the label now), ``speed_drop`` and ``seed``.
        """
        states, drops = self.states, self._drops
        return [
            Recording(out["t"][i], {k: v[i] for k, v in out.items() if k != "t"},
                      {"fleet": self.fleet, "machine": spec.machine, "state": states[i],
                       "speed_drop": float(drops[i]), "seed": self.seed})
            for i, spec in enumerate(self.specs)
        ]



def state_seeds(seed: int, state: str) -> tuple[int, int]:
    """(command seed, noise seed) of one health state, derived from a data set's seed and the state's name.

    The same (seed, state) always gives the same recording, whichever other states are simulated.
    """
    children = np.random.SeedSequence([int(seed), zlib.crc32(state.encode())]).spawn(2)
    return int(children[0].generate_state(1)[0]), int(children[1].generate_state(1)[0])


def simulate_states(
    states: Sequence[str],
    *,
    seconds: float = 1250.0,
    volts: tuple[float, float] = (0.0, 4.0),
    command: np.ndarray | None = None,
    nominal: PlantParameters | None = None,
    effects: Effects | None = None,
    noise: bool = True,
    seed: int = 0,
    fleet: str = "simulated",
) -> Iterator[Recording]:
    """One labelled recording per health state, as in the study's data sets (one machine per state).

    Each state gets its own derived seed (:func:`state_seeds`) for its excitation and sensor noise;
    the excitation is the study's filtered white noise (Eq. 3.21) on ``volts`` unless a ``command``
    is replayed (then the same command drives every state). Each run starts settled at its first
    command.

    Parameters
    ----------
    states : sequence of str
        Health-state names (``healthy``, ``<fault>_warning``, ``<fault>_alert``).
    seconds : float, default 1250
        Length of each recording, s (the study's data set per state); ignored with ``command``.
    volts : (float, float), default (0, 4)
        Voltage range of the excitation, V.
    command : ndarray, shape (n,), optional
        A recorded command to replay, V.
    nominal : PlantParameters, optional
        The healthy machine (default nominal); faults are calibrated against it.
    effects : mapping, optional
        Effects switched on in every state.
    noise : bool, default True
        Sensor noise.
    seed : int, default 0
        Data set seed.
    fleet : str, default "simulated"
        Fleet id written into each recording's metadata.

    Yields
    ------
    Recording
        ``meta``: ``fleet``, ``machine`` (= the state), ``state``, ``fault``, ``level``, ``severity``,
        ``speed_drop``, ``volts``, ``seed`` (the state's noise seed), ``dataset_seed``, and the
        simulator's ``parameters``, ``effects``, ``noise``, ``settled``.
    """
    healthy = nominal if nominal is not None else PlantParameters()
    for state in states:
        parse_state(state)
    for state in states:
        fault, level = parse_state(state)
        command_seed, noise_seed = state_seeds(seed, state)
        voltage = command if command is not None else filtered_noise(seconds, volts, seed=command_seed)
        severity = 0.0 if fault is None or level is None else level_severity(fault, level, healthy)
        meta = {
            "fleet": fleet, "machine": state, "state": state, "fault": fault, "level": level,
            "severity": severity, "speed_drop": LEVELS[level] if level else 0.0,
            "volts": None if command is not None else list(volts), "dataset_seed": int(seed),
        }
        yield simulate(voltage, state_parameters(state, healthy), effects, noise=noise, seed=noise_seed, meta=meta)
