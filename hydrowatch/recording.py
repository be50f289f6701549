"""A recording: one machine over one stretch of time at a fixed sample rate, in memory.

This is the in-memory form every part of hydrowatch exchanges (the simulator makes it, the file
formats in :mod:`hydrowatch.io` read and write it, identification and scoring consume it).
Channel names and units are the contract's (../shared/docs/contract.md), declared once in
:mod:`hydrowatch.channels`; the names below are views of :data:`~hydrowatch.channels.PLANT`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import DataError

SAMPLE_RATE_HZ = 200.0
"""Sample rate of every recording, Hz."""

INPUT = PLANT.command
"""The command channel every reference model is driven by."""
SENSORS: tuple[str, ...] = PLANT.sensors
"""The three sparse sensors the health methods use, in contract order; a recording has at least one."""

UNITS: dict[str, str] = PLANT.units
"""Unit of ``t`` and of every channel (:data:`hydrowatch.channels.PLANT`)."""
REQUIRED_CHANNELS: tuple[str, ...] = PLANT.required
"""Channels every recording has: the command (and, besides, at least one of :data:`SENSORS`:
:meth:`PLANT.missing <hydrowatch.channels.ChannelSet.missing>` checks both)."""
OPTIONAL_CHANNELS: tuple[str, ...] = PLANT.optional
"""Channels a recording may lack: each sensor (one at least stays) and the condition measurements."""


@dataclass
class Recording:
    """Samples of one machine.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times, s, strictly increasing.
    channels : dict of str to ndarray, shape (n,)
        ``voltage`` [V], at least one of ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m], and
        optionally ``supply_pressure``, ``load_pressure`` [bar], ``temperature`` [°C].
    meta : dict
        ``fleet``, ``machine``, ``state`` (health label, or None), and anything else worth keeping
        (seed, parameters, effects).
    """

    t: np.ndarray
    channels: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.float64)
        self.channels = {k: np.asarray(v, dtype=np.float64) for k, v in self.channels.items()}
        n = self.t.shape[0]
        for name, values in self.channels.items():
            if values.shape != (n,):
                raise DataError(
                    f"channel '{name}' must have shape ({n},) like 't'. Got {values.shape}.",
                    self.meta.get("source"),
                )

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "t":
            return self.t
        try:
            return self.channels[name]
        except KeyError:
            raise KeyError(f"recording has no channel '{name}'; it has {sorted(self.channels)}") from None

    @property
    def state(self) -> str | None:
        """Health label of the recording, or None when unknown."""
        return self.meta.get("state")

    @property
    def duration(self) -> float:
        """Length in seconds (n / sample rate)."""
        return len(self) / SAMPLE_RATE_HZ

    def slice(self, start: int, stop: int) -> Recording:
        """Samples ``start:stop`` as a new recording sharing the metadata (per-sample ``labels`` sliced with it)."""
        meta = dict(self.meta)
        labels = meta.get("labels")
        if labels is not None and len(labels) == len(self.t):
            meta["labels"] = labels[start:stop]
        return Recording(self.t[start:stop], {k: v[start:stop] for k, v in self.channels.items()}, meta)

    @classmethod
    def from_columns(cls, columns: Mapping[str, np.ndarray], meta: Mapping[str, Any] | None = None) -> Recording:
        """Build from a mapping that includes ``t``; other keys become channels."""
        cols = dict(columns)
        if "t" not in cols:
            raise DataError("column 't' [s] is missing.", (meta or {}).get("source"))
        t = cols.pop("t")
        return cls(t, cols, dict(meta or {}))
