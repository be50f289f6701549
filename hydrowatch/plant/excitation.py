"""Valve commands at 200 Hz: the study's filtered white noise, test signals, duty cycles, replays.

Every generator returns a command ``voltage`` as an ndarray of shape (n,), V, sampled at
``sample_rate`` (default 200 Hz, n = round(seconds·sample_rate)). Random ones take a ``seed``
(an int, or a ``numpy.random.Generator``) and are reproducible.

The identification input of the study (Eq. 3.21) is white noise through a first-order low-pass
filter, y(t) = 0.9·y(t−1) + 0.1·w(t) (the printed denominator 1 + 0.9·q⁻¹ has the pole's sign
wrong; the intended gentle low-pass is used, plant-model.md "Excitation"), scaled onto a voltage
range and clipped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.recording import SAMPLE_RATE_HZ

NOISE_POLE = 0.9
"""Pole of the study's first-order noise filter (Eq. 3.21)."""
NOISE_SIGMAS = 2.5
"""Filtered-noise standard deviations that span half the voltage range (≈ 1.2 % of samples clipped)."""

Seed = int | np.random.Generator | None


def _rng(seed: Seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def n_samples(seconds: float, sample_rate: float = SAMPLE_RATE_HZ) -> int:
    """Number of samples in ``seconds`` at ``sample_rate`` (at least 1)."""
    if not (math.isfinite(seconds) and seconds > 0):
        raise ParameterError(f"seconds must be a positive, finite duration. Got {seconds!r}.")
    if not (math.isfinite(sample_rate) and sample_rate > 0):
        raise ParameterError(f"sample_rate must be a positive number of Hz. Got {sample_rate!r}.")
    return max(1, int(round(seconds * sample_rate)))


def check_volts(volts: tuple[float, float]) -> tuple[float, float]:
    """Validate a voltage range (lo, hi), V, lo < hi, both finite."""
    lo, hi = (float(v) for v in volts)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ParameterError(f"voltage range must be finite with lo < hi. Got {volts!r}. Give e.g. (0.0, 4.0).")
    return lo, hi


def parse_volts(text: str) -> tuple[float, float]:
    """Read a voltage range written ``LO:HI`` (e.g. ``"0:4"``), V."""
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        volts = (float(parts[0]), float(parts[1]))
    except ValueError:
        raise ParameterError(f"voltage range must be written LO:HI in volts. Got {text!r}. Give e.g. 0:4.") from None
    return check_volts(volts)


def filtered_noise(seconds: float, volts: tuple[float, float] = (0.0, 4.0), *, seed: Seed = None,
                   pole: float = NOISE_POLE, sigmas: float = NOISE_SIGMAS,
                   sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """The study's identification input: low-pass filtered white noise on a voltage range (Eq. 3.21).

    y(t) = pole·y(t−1) + (1 − pole)·w(t), w standard normal, started in its stationary
    distribution (no transient); then u = mid + half·y/(sigmas·σy), clipped onto [lo, hi], where
    mid, half are the range's centre and half-width and σy = (1 − pole)/√(1 − pole²).

    Parameters
    ----------
    seconds : float
        Duration, s.
    volts : (float, float), default (0, 4)
        Voltage range (lo, hi), V.
    seed : int or Generator, optional
        Noise seed.
    pole : float, default 0.9
        Filter pole in [0, 1) (0 = white noise).
    sigmas : float, default 2.5
        How many standard deviations of y map onto half the range (larger: less clipping).
    sample_rate : float, default 200
        Hz.

    Returns
    -------
    ndarray, shape (n,)
        Command, V.
    """
    lo, hi = check_volts(volts)
    if not 0.0 <= pole < 1.0:
        raise ParameterError(f"noise filter pole must be in [0, 1). Got {pole!r}. The study uses 0.9.")
    if not (math.isfinite(sigmas) and sigmas > 0):
        raise ParameterError(f"sigmas must be positive. Got {sigmas!r}.")
    from scipy.signal import lfilter  # scipy.signal takes seconds to import; only load it when used

    n = n_samples(seconds, sample_rate)
    rng = _rng(seed)
    w = rng.standard_normal(n)
    sigma_y = (1.0 - pole) / math.sqrt(1.0 - pole * pole)
    b, a = [1.0 - pole], [1.0, -pole]
    y0 = rng.standard_normal() * sigma_y
    y, _ = lfilter(b, a, w, zi=[pole * y0])  # the filter's state as if y(−1) = y0
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return np.clip(mid + half * y / (sigmas * sigma_y), lo, hi)


class FilteredNoiseCommand:
    """Endless filtered-noise commands for M machines, chunk by chunk (the plant service's and the demo's).

    The same filter as :func:`filtered_noise`, y(t) = pole·y(t−1) + (1 − pole)·w(t), scaled onto
    the voltage range and clipped, but with the filter state kept per machine between chunks so an
    endless command has no seams.

    Parameters
    ----------
    n_machines : int
        M.
    volts : (float, float)
        Voltage range (lo, hi), V.
    seed : int or None
        Seed of the white noise (one generator for the whole fleet).
    """

    def __init__(self, n_machines: int, volts: tuple[float, float] = (0.0, 4.0), *, seed: int | None = None) -> None:
        self.n_machines = n_machines
        self.volts = check_volts(volts)
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self._sigma_y = (1.0 - NOISE_POLE) / math.sqrt(1.0 - NOISE_POLE**2)
        # filter state as if y(−1) were drawn from the stationary distribution (no transient)
        self._zi = NOISE_POLE * self._rng.standard_normal((n_machines, 1)) * self._sigma_y

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples of every machine's command, shape (M, n), V."""
        from scipy.signal import lfilter  # slow to import the first time (see filtered_noise)

        w = self._rng.standard_normal((self.n_machines, n))
        y, self._zi = lfilter([1.0 - NOISE_POLE], [1.0, -NOISE_POLE], w, axis=1, zi=self._zi)
        lo, hi = self.volts
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        return np.clip(mid + half * y / (NOISE_SIGMAS * self._sigma_y), lo, hi)


def steps(seconds: float, levels: Sequence[float], *, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """A staircase: each level held for an equal share of ``seconds``.

    Parameters
    ----------
    seconds : float
        Duration, s.
    levels : sequence of float
        Command levels, V, in order.

    Returns
    -------
    ndarray, shape (n,)
        Command, V.
    """
    values = np.asarray(levels, dtype=np.float64)
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)):
        raise ParameterError(f"step levels must be a non-empty list of finite volts. Got {levels!r}.")
    n = n_samples(seconds, sample_rate)
    return values[np.minimum(np.arange(n) * values.size // n, values.size - 1)]


def ramp(seconds: float, start: float, stop: float, *, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """A straight ramp from ``start`` to ``stop`` V over ``seconds``; shape (n,), V."""
    return np.linspace(float(start), float(stop), n_samples(seconds, sample_rate))


def sine(seconds: float, frequency: float, offset: float = 2.0, amplitude: float = 1.0, *,
         phase: float = 0.0, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """offset + amplitude·sin(2π·f·t + phase); frequency in Hz, offset and amplitude in V; shape (n,), V."""
    if not (math.isfinite(frequency) and 0.0 <= frequency < 0.5 * sample_rate):
        raise ParameterError(
            f"sine frequency must be in [0, {0.5 * sample_rate:g}) Hz (below Nyquist). Got {frequency!r}."
        )
    t = np.arange(n_samples(seconds, sample_rate)) / sample_rate
    return offset + amplitude * np.sin(2.0 * math.pi * frequency * t + phase)


def chirp(seconds: float, f0: float, f1: float, offset: float = 2.0, amplitude: float = 1.0, *,
          method: str = "logarithmic", sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """A swept sine from f0 to f1 Hz over ``seconds`` around ``offset`` V; shape (n,), V.

    ``method`` is scipy.signal.chirp's: "linear", "quadratic", "logarithmic" (default; f0, f1 > 0).
    """
    for f in (f0, f1):
        if not (math.isfinite(f) and 0.0 < f < 0.5 * sample_rate):
            raise ParameterError(f"chirp frequencies must be in (0, {0.5 * sample_rate:g}) Hz. Got {f!r}.")
    from scipy.signal import chirp as swept_sine  # lazy, as in filtered_noise

    n = n_samples(seconds, sample_rate)
    t = np.arange(n) / sample_rate
    return offset + amplitude * swept_sine(t, f0, t[-1] if n > 1 else 1.0, f1, method=method, phi=-90.0)


def duty_cycle(seconds: float, volts: tuple[float, float] = (0.0, 4.0), *, seed: Seed = None,
               segment_seconds: tuple[float, float] = (2.0, 20.0),
               sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """A working duty cycle: holds, ramps and steps between random levels on a voltage range.

    The command is a chain of segments of random length (uniform in ``segment_seconds``); each is
    a hold at the current level, a step to a new random level then a hold, or a straight ramp to a
    new random level (each with probability 1/3). Levels are uniform on [lo, hi].

    Parameters
    ----------
    seconds : float
        Duration, s.
    volts : (float, float), default (0, 4)
        Voltage range, V.
    seed : int or Generator, optional
        Seed of the random levels and lengths.
    segment_seconds : (float, float), default (2, 20)
        Shortest and longest segment, s.

    Returns
    -------
    ndarray, shape (n,)
        Command, V.
    """
    lo, hi = check_volts(volts)
    shortest, longest = (float(s) for s in segment_seconds)
    if not (0.0 < shortest <= longest and math.isfinite(longest)):
        raise ParameterError(f"segment_seconds must satisfy 0 < shortest <= longest. Got {segment_seconds!r}.")
    n = n_samples(seconds, sample_rate)
    rng = _rng(seed)
    out = np.empty(n)
    level = float(rng.uniform(lo, hi))
    i = 0
    while i < n:
        length = min(n - i, max(1, int(round(rng.uniform(shortest, longest) * sample_rate))))
        kind = rng.integers(3)
        target = float(rng.uniform(lo, hi))
        if kind == 0:  # hold
            out[i:i + length] = level
        elif kind == 1:  # step, then hold
            level = target
            out[i:i + length] = level
        else:  # ramp
            out[i:i + length] = np.linspace(level, target, length + 1)[1:]
            level = target
        i += length
    return out


def read_command(path: str | Path, *, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """The ``voltage`` column of a CSV or Parquet file, to replay as a command.

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.parquet`` file with a ``voltage`` column [V] (and optionally ``t`` [s]).
    sample_rate : float, default 200
        Hz; when the file has a ``t`` column its spacing must match 1/sample_rate.

    Returns
    -------
    ndarray, shape (n,)
        Command, V.

    Raises
    ------
    DataError
        Naming the file: unreadable, unknown suffix, no or non-numeric ``voltage``, NaN, wrong spacing.
    """
    source = str(path)
    p = Path(path)
    if not p.is_file():
        raise DataError("command file must exist. Got a missing path. Give a CSV or Parquet file.", source)
    suffix = p.suffix.lower()
    try:
        if suffix == ".csv":
            from pyarrow import csv as pa_csv

            table = pa_csv.read_csv(p)
        elif suffix in (".parquet", ".pq"):
            from pyarrow import parquet as pq

            table = pq.read_table(p)
        else:
            raise DataError(f"command file must be .csv or .parquet. Got suffix {suffix!r}.", source)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DataError(f"command file must be a readable table. Got: {str(exc).splitlines()[0]}", source) from None
    if "voltage" not in table.column_names:
        raise DataError(f"command file must have a 'voltage' column [V]. Got columns {table.column_names}.", source)
    voltage = _numeric_column(table, "voltage", source)
    if voltage.size == 0:
        raise DataError("command file must hold at least one sample. Got an empty table.", source)
    bad = np.flatnonzero(~np.isfinite(voltage))
    if bad.size:
        raise DataError(f"column 'voltage' must be finite. Got NaN/inf at row {int(bad[0])}. Fill or drop it.",
                        source)
    if "t" in table.column_names and voltage.size > 1:
        dt = np.diff(_numeric_column(table, "t", source))
        expected = 1.0 / sample_rate
        wrong = np.flatnonzero(~(np.abs(dt - expected) <= 1e-3 * expected))
        if wrong.size:
            raise DataError(
                f"column 't' must step by {expected:g} s ({sample_rate:g} Hz). Got {dt[wrong[0]]!r} s after row "
                f"{int(wrong[0])}. Resample the command to {sample_rate:g} Hz.",
                source,
            )
    return voltage


def _numeric_column(table: pa.Table, name: str, source: str) -> np.ndarray:
    column = table.column(name)
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        raise DataError(f"column '{name}' must be numeric. Got type {column.type}.", source)
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)
