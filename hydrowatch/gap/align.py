"""Line a recording up with the simulator: the recorded command drives the model, samples match.

The initial state of the rig is unknown. The model starts from the steady state at the first
command (``PlantSimulator.settle``) and the first ``burn_in_s`` seconds are left out of every cost
and statistic; the plant forgets its initial state much faster (hydraulic resonance ≈ 28 Hz,
mechanical time constant ≈ 0.1 s). The rest is cut into blocks; every ``holdout_every``-th block is
held out of fitting and used only to judge (the contract's "NRMSE on held-out data").
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.gap.simulations import Simulations
from hydrowatch.plant.effects import Effects
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import PlantSimulator
from hydrowatch.recording import INPUT, SAMPLE_RATE_HZ, SENSORS, Recording

MIN_SECONDS = 8.0
"""Shortest recording the analysis accepts, s."""


@dataclass(frozen=True)
class AlignedRecording:
    """A recording ready for output-error fitting.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times, s.
    voltage : ndarray, shape (n,)
        Recorded command, V.
    measured : ndarray, shape (3, n)
        Flow [L/min], speed [rad/s], torque [N·m].
    scale : ndarray, shape (3,)
        Standard deviation of each measured sensor after the burn-in (NRMSE denominators).
    fit_mask, holdout_mask : ndarray of bool, shape (n,)
        Samples used for fitting and for judging; both exclude the burn-in.
    source : str
        Where the data came from (file path or ``"recording"``).
    simulations : Simulations
        The models simulated on this recording so far, shared with its heads (:func:`simulate_sensors`; one
        analysis's, emptied when it ends).
    """

    t: np.ndarray
    voltage: np.ndarray
    measured: np.ndarray
    scale: np.ndarray
    fit_mask: np.ndarray
    holdout_mask: np.ndarray
    source: str
    simulations: Simulations = field(default_factory=Simulations, compare=False, repr=False)

    @property
    def used_mask(self) -> np.ndarray:
        """Samples after the burn-in, shape (n,)."""
        return self.fit_mask | self.holdout_mask

    @property
    def duration(self) -> float:
        """Length, s."""
        return self.t.size / SAMPLE_RATE_HZ

    def head(self, seconds: float) -> AlignedRecording:
        """The first ``seconds`` (same masks and scales), or self when the record is not longer."""
        n = int(round(seconds * SAMPLE_RATE_HZ))
        if n >= self.t.size:
            return self
        return AlignedRecording(self.t[:n], self.voltage[:n], self.measured[:, :n], self.scale, self.fit_mask[:n],
                                self.holdout_mask[:n], self.source, self.simulations)


def align(
    recording: Recording, *, burn_in_s: float = 1.0, block_s: float = 3.0, holdout_every: int = 3
) -> AlignedRecording:
    """Check a recording and split it into fitting and held-out blocks.

    Parameters
    ----------
    recording : Recording
        Must hold ``voltage``, ``flow``, ``speed``, ``torque`` at 200 Hz, finite, at least MIN_SECONDS long.
    burn_in_s : float, default 1.0
        Seconds at the start left out while the model forgets its initial state.
    block_s : float, default 3.0
        Length of the interleaved blocks, s.
    holdout_every : int, default 3
        Every ``holdout_every``-th block (the 2nd, 5th, …) is held out.

    Raises
    ------
    DataError
        A missing or non-finite channel, a wrong sample rate or a recording that is too short.
    """
    source = str(recording.meta.get("source", "recording"))
    if holdout_every < 2 or block_s <= 0 or burn_in_s < 0:
        raise ParameterError(
            f"holdout_every must be >= 2, block_s > 0 and burn_in_s >= 0. Got {holdout_every}, {block_s}, {burn_in_s}."
        )
    missing = [c for c in (INPUT, *SENSORS) if c not in recording.channels]
    if missing:
        raise DataError(f"channels {missing} must be present for the gap analysis. Got {sorted(recording.channels)}.",
                        source)
    t = recording.t
    if t.size > 1:
        dt = float(np.median(np.diff(t)))
        if abs(dt * SAMPLE_RATE_HZ - 1.0) > 1e-3:
            raise DataError(f"sample interval must be {1 / SAMPLE_RATE_HZ:g} s (200 Hz). Got {dt:g} s. Resample first.",
                            source)
    if t.size / SAMPLE_RATE_HZ < MIN_SECONDS + burn_in_s:
        raise DataError(
            f"recording must last at least {MIN_SECONDS + burn_in_s:g} s. Got {t.size / SAMPLE_RATE_HZ:g} s. "
            "Record longer (20–120 s of filtered-noise command is typical).", source)
    columns = [recording[c] for c in (INPUT, *SENSORS)]
    for name, values in zip((INPUT, *SENSORS), columns):
        if not np.all(np.isfinite(values)):
            raise DataError(f"channel '{name}' must be finite. Got {int((~np.isfinite(values)).sum())} NaN/inf "
                            "samples. Drop or fill them before the analysis.", source)
    n = t.size
    start = int(round(burn_in_s * SAMPLE_RATE_HZ))
    block = np.maximum(np.arange(n) - start, 0) // int(round(block_s * SAMPLE_RATE_HZ))
    after = np.arange(n) >= start
    holdout = after & (block % holdout_every == 1)
    measured = np.vstack(columns[1:])
    scale = measured[:, after].std(axis=1)
    if np.any(scale <= 0):
        raise DataError("every sensor must vary over the recording. Got a constant channel. "
                        "Use an exciting command (filtered noise, steps).", source)
    return AlignedRecording(t, columns[0], measured, scale, after & ~holdout, holdout, source)


def simulate_sensors(
    aligned: AlignedRecording,
    parameters: Sequence[PlantParameters],
    effects: Sequence[Effects | None],
    stop: int | None = None,
) -> np.ndarray:
    """Noise-free simulation of M candidate models driven by the recorded command, in one batched call.

    Parameters
    ----------
    aligned : AlignedRecording
        The recording (its command and start time t0, which fixes the pump ripple's phase).
    parameters : sequence of PlantParameters, length M
    effects : sequence of effect mappings or None, length M
    stop : int, optional
        Simulate only the first ``stop`` samples (default: all n).

    Returns
    -------
    ndarray, shape (M, 3, n) (n = ``stop`` when given)
        Simulated flow [L/min], speed [rad/s], torque [N·m].

    The M models are shared out over :func:`simulation_threads` threads. A model the recording's
    :class:`Simulations` holds for at least as many samples is taken from there, not simulated again (the same
    numbers: issue 12, item 5), and every model simulated here is kept there.
    """
    params, effs = list(parameters), list(effects)
    kept = aligned.simulations
    if not params or not kept.serves(aligned.voltage, float(aligned.t[0])):
        return _simulate_models(aligned, params, effs, stop)
    n = aligned.voltage[:stop].size
    keys = [kept.key(p, e) for p, e in zip(params, effs)]
    out: list[np.ndarray | None] = [kept.take(k, n) for k in keys]
    todo: dict[tuple[bytes, bytes], int] = {}
    for i, (k, o) in enumerate(zip(keys, out)):
        if o is None:
            todo.setdefault(k, i)
    if todo:
        first = list(todo.values())
        preds = _simulate_models(aligned, [params[i] for i in first], [effs[i] for i in first], stop)
        for k, pred in zip(todo, preds):
            kept.keep(k, pred)
        made = dict(zip(todo, preds))
        out = [made[k] if o is None else o for k, o in zip(keys, out)]
    return np.stack(out)  # type: ignore[arg-type]


def _simulate_models(aligned: AlignedRecording, params: list[PlantParameters], effs: list[Effects | None],
                     stop: int | None) -> np.ndarray:
    """Simulate every model (shape (M, 3, n)), shared out over :func:`simulation_threads` threads."""
    workers = min(simulation_threads(), len(params))
    if workers <= 1:
        return _simulate_batch(aligned, params, effs, stop)
    chunks = np.array_split(np.arange(len(params)), workers)
    with ThreadPoolExecutor(workers) as pool:
        parts = pool.map(lambda idx: _simulate_batch(aligned, [params[i] for i in idx], [effs[i] for i in idx], stop),
                         chunks)
        return np.concatenate(list(parts), axis=0)


def simulation_threads() -> int:
    """Threads the batched simulations of the analysis share out their models to, and how many of its independent
    steps run side by side (side_by_side.py; each of those shares its own simulations out again): the environment's
    ``HYDROWATCH_THREADS``, else min(2, CPU count) (issue 12, item 5: "under 5 minutes on 2 cores";
    the compiled kernel releases the GIL, each thread runs its own simulator on its own models, so
    the results do not depend on the count). Set ``HYDROWATCH_THREADS=1`` on a shared machine."""
    value = os.environ.get("HYDROWATCH_THREADS", "")
    if value.strip():
        try:
            return max(int(value), 1)
        except ValueError:
            raise ParameterError(f"HYDROWATCH_THREADS must be a positive integer. Got {value!r}.") from None
    return min(2, os.cpu_count() or 1)


def _simulate_batch(aligned: AlignedRecording, parameters: list[PlantParameters], effects: list[Effects | None],
                    stop: int | None) -> np.ndarray:
    sim = PlantSimulator(parameters, effects, noise=False, t0=float(aligned.t[0]))
    sim.settle(float(aligned.voltage[0]))
    command = aligned.voltage[:stop]
    out = sim.step(np.broadcast_to(command, (len(parameters), command.size)))
    return np.stack([out[name] for name in SENSORS], axis=1)
