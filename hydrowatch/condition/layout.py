"""The raw window layout of the parity method: channel order, checks, and cutting a recording into windows.

A raw window is an array (window, 4) of voltage [V], flow [L/min], speed [rad/s], torque [N·m] in :data:`CHANNELS`
order, with the oil temperature [°C] as a 5th column when the recording has one (:data:`TEMPERATURE`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.condition.oil import temperature_known
from hydrowatch.errors import DataError
from hydrowatch.health.windows import check_window, sliding_windows
from hydrowatch.recording import INPUT, SENSORS, Recording

CHANNELS: tuple[str, ...] = (INPUT, *SENSORS)
"""Channel order of a window's last axis (4 channels)."""
WIDTH = len(CHANNELS)
"""Channels of a window without the oil temperature (4); with it, the temperature is column WIDTH."""
TEMPERATURE = "temperature"
"""Optional 5th channel of a window: oil temperature, °C (absent or all NaN: unknown, the leak boxes allow for the
oil's range, :mod:`hydrowatch.condition.oil`)."""


def check_windows(windows: np.ndarray, window: int) -> np.ndarray:
    """Validate raw windows, shape (m, window, 4) in :data:`CHANNELS` order, or 5 with the oil temperature [°C]."""
    w = np.asarray(windows, dtype=np.float64)
    if w.ndim == 2 and w.shape[0] == window and w.shape[1] in (WIDTH, WIDTH + 1):
        w = w[None]
    if w.ndim != 3 or w.shape[1] != window or w.shape[2] not in (WIDTH, WIDTH + 1):
        raise DataError(
            f"windows must have shape (n_windows, {window}, {WIDTH} or {WIDTH + 1}) with channels {list(CHANNELS)} "
            f"[+ {TEMPERATURE}]. Got {w.shape}. Cut recordings with windows_from_recording."
        )
    return w


def invalid_reasons(windows: np.ndarray, sensors: Sequence[str]) -> list[str | None]:
    """Why each valid-shaped window (m, n, 4 or 5) cannot be judged, or None (``ConditionFeatures.window_reasons``)."""
    used = [0] + [1 + SENSORS.index(s) for s in sensors] + ([WIDTH] if windows.shape[2] > WIDTH else [])
    names = (*CHANNELS, TEMPERATURE)
    bad = (~np.isfinite(windows[:, :, used])).sum(axis=1)  # (m, used)
    if windows.shape[2] > WIDTH:  # a temperature all NaN is unknown oil (condition/oil.py), not a gap
        bad[~temperature_known(windows, WIDTH), -1] = 0
    stuck = np.ptp(np.nan_to_num(windows[:, :, used]), axis=1) == 0.0
    reasons: list[str | None] = []
    for i in range(windows.shape[0]):
        why = None
        for j, c in enumerate(used):
            if bad[i, j]:
                why = f"{names[c]}: {int(bad[i, j])} NaN/inf samples in the window"
                break
            if 0 < c < WIDTH and stuck[i, j]:
                why = f"{names[c]}: constant over the window (stuck sensor?)"
                break
        reasons.append(why)
    return reasons



def windows_from_recording(rec: Recording, window: int = 1000, hop: int = 1000,
                           temperature: bool | None = None) -> np.ndarray:
    """Raw windows of a recording, shape (n_windows, window, 4) or (n_windows, window, 5).

    Channels: voltage [V], flow [L/min], speed [rad/s], torque [N·m], and the oil temperature
    [°C] as 5th channel when ``temperature`` is True, or None (default) and the recording has
    one; window k covers samples ``[k·hop, k·hop + window)``. A sensor the recording lacks is NaN
    (a model whose ``sensors`` leave it out fills it from the relations; for one that reads it, every
    window is invalid).
    """
    check_window(window, hop)
    channels = list(CHANNELS)
    has = TEMPERATURE in rec.channels
    if temperature and not has:
        raise DataError(f"recording must have a '{TEMPERATURE}' channel when temperature=True. "
                        f"Got channels {sorted(rec.channels)}. Pass temperature=None to use it when present.")
    if has and temperature is not False:
        channels.append(TEMPERATURE)
    nan = np.full(len(rec), np.nan)
    return np.stack([sliding_windows(rec.channels.get(c, nan), window, hop) for c in channels], axis=-1)
