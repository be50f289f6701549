"""A machine's degradation index over its windows, and what a forecast of each part reads: :class:`Degradation`.

:func:`~hydrowatch.condition.degradation.window_degradation` makes it (files; online one window at a time,
:mod:`~hydrowatch.condition.degradation_stream`). Besides each part's index and interval per window it keeps what the
forecast needs: whether a value is the part's own estimate (``measured``), the values of a part blamed before its
pool could tell it apart (``provisional``, joining its history once a later pool confirms it,
:func:`~hydrowatch.condition.attribution.confirmed`), and the windows where the relief spring and the coil **share
one index** (``shared``).

**A shared index** (2026-12-03, stop 58). On a unit whose commissioning barely saw the relief
(:func:`~hydrowatch.condition.unit_checks.relief_barely_seen`), the pool cannot tell a wearing relief spring from a
wearing coil (:data:`~hydrowatch.condition.attribution.LOOK_ALIKES`) until about the warning: neither has an index
there, and a relief spring whose history begins only when it is told apart had no forecast when its index passed 0.5
(three of 16 such paths, "too short") or one from a few windows (28.6 % early). Yet in those windows the two
hypotheses' own indices agree: median |coil − relief| 0.003–0.034 per band of the true index on the relief paths of
five such units, each within 0.02 of the truth in median (seeds 3001–3004, ``recordings/diag58/pair.py``): the
speed drop is known, only not which of the two parts causes it. So where the pool leaves exactly that pair untold
and the blamed one reads at least :data:`~hydrowatch.condition.attribution.UNTOLD_LEVEL` (its provisional value),
the pair's index is each part's history for the forecast where it has none of its own, and a forecast made while
the last window is so says ``untold_from`` the other part: "this part, or that one". ``score --json``'s windows and
the health message are unchanged (neither part has an index there).

**One reading of the pair** (2026-12-04, stop 63). The index the pair shares in a window is the mean of the two
parts' own readings there (each hypothesis's index on its own fit, where the fit determines it), not the blamed
one's: which of the two the pool blames switches while they are untold, and their readings differ by a few
hundredths (on fresh flagged unit 3029/38's relief path the coil's read −0.003 to −0.009 from the truth at true
0.1–0.4, the relief's +0.001 to +0.006 from 0.4 on), so a history that followed the blame stepped up where the blame
moved, the accelerating trend won and the relief's forecast came 41.2 % early; on the mean, 3.3 % (docs/
degradation.md, "One reading of the pair").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.attribution import LOOK_ALIKES, confirmed
from hydrowatch.condition.index_table import LEAK, LeakReading

SHARED_PAIR: tuple[str, str] = (parity.VALVE_HYPOTHESES[LOOK_ALIKES[0]], parity.VALVE_HYPOTHESES[LOOK_ALIKES[1]])
"""The parts that can share one index (relief_spring, valve_coil)."""


@dataclass(frozen=True)
class Degradation:
    """Index per fault and window with its 95 % interval: ``value``, ``low``, ``high``, each fault → (n,).

    NaN where the window is invalid, the sensors cannot test the fault's relation, or the window's fit does not
    determine the part (:data:`~hydrowatch.condition.degradation.DETERMINED_STEP`). ``measured`` (fault → bool
    (n,)) is False where the value is not the part's own estimate: a valve-side part another one was blamed for
    (it reads 0 there).
    """

    value: Mapping[str, np.ndarray]
    low: Mapping[str, np.ndarray]
    high: Mapping[str, np.ndarray]
    measured: Mapping[str, np.ndarray]
    provisional: Mapping[str, np.ndarray] | None = None
    """fault → (n,): the blamed valve-side part's own index where the pool could not yet tell it from a look-alike
    (its ``value`` NaN there), NaN elsewhere; None: none kept."""
    valid: np.ndarray | None = None
    """(n,) bool: the windows the attribution pool counts (valid ones); None: every window."""
    held: int = -1
    """The valve-side part held after the last window (:func:`~.attribution.contenders`; −1: none): where an online
    stream's next window starts."""
    shared: np.ndarray | None = None
    """(n,) bool: windows where :data:`SHARED_PAIR` share one index (module docstring); None: none."""
    pair: np.ndarray | None = None
    """(n,): the index :data:`SHARED_PAIR` share in each :attr:`shared` window, NaN elsewhere (module docstring,
    "One reading of the pair"); None: none."""
    leak: LeakReading | None = None
    """What re-reads pump_leak's history on the machine's latest pump capacity where commissioning left it
    undetermined (:mod:`~hydrowatch.condition.index_table`); None: the capacity is θ0's."""

    def pair_index(self, end: int) -> np.ndarray:
        """The shared pair's index in windows 0..end − 1 (:attr:`pair`), NaN where not :attr:`shared`, shape
        (end,)."""
        if self.shared is None or self.pair is None:
            return np.full(end, np.nan)
        return np.where(self.shared[:end], self.pair[:end], np.nan)

    def history(self, fault: str, upto: int | None = None) -> np.ndarray:
        """The part's own index, NaN elsewhere, shape (n,) (or (upto + 1,): as known at window ``upto``), with the
        provisional values a later pool confirmed (:func:`~.attribution.confirmed`) and, for a part of
        :data:`SHARED_PAIR`, the pair's index where it shared one and has none of its own, and pump_leak's re-read
        on the latest capacity (:attr:`leak`): what a forecast reads."""
        end = self.value[fault].size if upto is None else upto + 1
        own = np.where(self.measured[fault][:end], self.value[fault][:end], np.nan)
        if self.provisional is not None:
            valid = np.ones(end, dtype=bool) if self.valid is None else self.valid[:end]
            own[valid] = confirmed(own[valid], self.provisional[fault][:end][valid])
        if fault in SHARED_PAIR:
            pair = self.pair_index(end)
            own = np.where(np.isnan(own), pair, own)
        if fault == LEAK and self.leak is not None:
            own = self.leak.reread(own)
        return own

    def _last_valid(self, fault: str, upto: int | None) -> int | None:
        rows = np.arange(self.value[fault].size) if self.valid is None else np.flatnonzero(self.valid)
        rows = rows if upto is None else rows[rows <= upto]
        return int(rows[-1]) if rows.size else None

    def untold_from(self, fault: str, upto: int | None = None) -> str | None:
        """The part ``fault`` shares its index with in the latest valid window (up to ``upto``) where either part of
        the pair reads one (its own or a provisional value: a window that determines neither, such as the coil's
        with the pump at its limit throughout, says nothing of which), None where it shares none: a forecast of
        ``fault`` then is of it or that part."""
        if fault not in SHARED_PAIR or self.shared is None:
            return None
        last = self._last_saying(upto)
        if last is None or not self.shared[last]:
            return None
        return next(f for f in SHARED_PAIR if f != fault)

    def _last_saying(self, upto: int | None) -> int | None:
        """The latest valid window (up to ``upto``) where either part of :data:`SHARED_PAIR` reads a value (its own,
        a 0 while the other is blamed, or a provisional one), None if none."""
        end = self.value[SHARED_PAIR[0]].size if upto is None else upto + 1
        says = np.zeros(end, dtype=bool)
        for f in SHARED_PAIR:
            says |= np.isfinite(self.value[f][:end])
            if self.provisional is not None:
                says |= np.isfinite(self.provisional[f][:end])
        if self.valid is not None:
            says &= self.valid[:end]
        rows = np.flatnonzero(says)
        return int(rows[-1]) if rows.size else None

    def ruled_out(self, fault: str, upto: int | None = None) -> bool:
        """Whether the last valid window (up to ``upto``) rules the part out: a valve-side part another was blamed
        for by the margin, reading 0 (:func:`~hydrowatch.condition.forecast.ruled_out_forecast`); not where it
        shares the pair's index. For a part of a pair that shared one, the latest window that reads either part
        decides (:meth:`untold_from`'s): a window that reads neither (both untold, neither determined) says nothing
        of which, and the pair's shared history is the other part's once that part was told apart."""
        end = self.value[fault].size if upto is None else upto + 1
        if fault in SHARED_PAIR and self.shared is not None and self.shared[:end].any():  # as online
            last = self._last_saying(upto)
            sharing = last is not None and bool(self.shared[last])  # untold_from's answer, without a second scan
        else:
            last, sharing = self._last_valid(fault, upto), False  # no shared window yet: untold_from is None
        return (last is not None and not sharing and not self.measured[fault][last]
                and self.value[fault][last] == 0.0)

    def parts(self) -> list[str]:
        """The parts a forecast of these windows covers: each with an index in some window, and the pair where
        it shared one."""
        sharing = self.shared is not None and bool(self.shared.any())
        return [f for f in self.value if np.isfinite(self.value[f]).any() or (sharing and f in SHARED_PAIR)]

    def window(self, i: int, measured: bool = False) -> dict[str, dict[str, Any]]:
        """``score --json``'s ``degradation`` of window ``i``: {FAULT: {"value", "ci95": [lo, hi]}}, finite only;
        with ``measured`` each entry also says whether the value is the part's own estimate (what a forecast of
        the machine's history reads, :meth:`history`), a provisional entry of a window sharing the pair's index
        names the other part (``"untold_from"``) and carries the pair's index (``"pair"``), and pump_leak's
        carries what re-reads it (``"reading"``, :meth:`~hydrowatch.condition.index_table.LeakReading.at`) where
        :attr:`leak` is kept."""
        out: dict[str, dict[str, Any]] = {
            f: {"value": round(float(self.value[f][i]), 4),
                "ci95": [round(float(self.low[f][i]), 4), round(float(self.high[f][i]), 4)]}
            for f in self.value if np.isfinite(self.value[f][i])}
        if measured:
            for f, entry in out.items():
                entry["measured"] = bool(self.measured[f][i])
            shared = self.shared is not None and bool(self.shared[i])
            for f, p in (self.provisional or {}).items():
                if np.isfinite(p[i]):  # blamed, not yet told apart: for the forecast's history, not published
                    out[f] = {"value": round(float(p[i]), 4), "measured": False, "provisional": True}
                    if shared and f in SHARED_PAIR:
                        out[f]["untold_from"] = next(g for g in SHARED_PAIR if g != f)
                        out[f]["pair"] = round(float(self.pair[i]), 4) if self.pair is not None else float("nan")
            if LEAK in out and self.leak is not None and np.isfinite(self.leak.capacity[i]):
                out[LEAK]["reading"] = self.leak.at(i)
        return out
