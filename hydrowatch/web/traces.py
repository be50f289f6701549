"""A machine's last windows of measured and expected sensors (``expected_window`` messages), as its page charts them.

:class:`ExpectedTrace` is fed one message at a time (river style: :meth:`ExpectedTrace.add` returns nothing,
:meth:`ExpectedTrace.to_dict` reads) and keeps the last ``windows`` windows: 50 points per sensor and window from
the scorer (0.1 s means), so 6 windows (30 s) are 300 points per line, about what a 960-pixel chart shows.
"""

from __future__ import annotations

import sys
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

from hydrowatch.errors import ParameterError


class ExpectedTrace:
    """The last ``windows`` ``expected_window`` messages of one machine.

    Parameters
    ----------
    windows : int, default 6
        Windows kept (the oldest goes when one more comes; 6 are 30 s of the scorer's 5 s windows).
    """

    def __init__(self, windows: int = 6) -> None:
        if int(windows) != windows or windows < 1:
            raise ParameterError(f"windows must be an integer >= 1. Got {windows!r}; 6 is the default.")
        self.windows = int(windows)
        self._kept: deque[tuple[float, float, dict[str, dict[str, Any]]]] = deque(maxlen=self.windows)

    def __len__(self) -> int:
        return len(self._kept)

    def add(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Take one message's rows (one per sensor, as ``RecordBatch.to_pylist`` gives them). A window that does not
        come after the last one kept (a restarted stream starts its time again) starts the trace again."""
        if not rows:
            return
        start, end = float(rows[0]["window_start"]), float(rows[0]["window_end"])
        if self._kept and start < self._kept[-1][1] - 1e-9:
            self._kept.clear()
        sensors = {sys.intern(str(r["sensor"])): {
            "unit": r["unit"], "source": r["source"], "step": float(r["step"]),
            "measured": list(r["measured"]), "expected": list(r["expected"])} for r in rows}
        self._kept.append((start, end, sensors))

    def to_dict(self) -> dict[str, Any] | None:
        """Per sensor, oldest point first: ``unit``, ``source``, ``t`` (each point's middle, s), ``measured`` and
        ``expected`` (None where consecutive windows leave a gap: the chart breaks its lines there); None when
        nothing was added."""
        if not self._kept:
            return None
        out: dict[str, dict[str, Any]] = {}
        last_end: dict[str, float] = {}
        for start, end, sensors in self._kept:
            for name, s in sensors.items():
                line = out.setdefault(name, {"unit": s["unit"], "source": s["source"], "t": [], "measured": [],
                                             "expected": []})
                line["source"] = s["source"]
                if name in last_end and start - last_end[name] > 0.5 * s["step"]:  # a window missing in between
                    for k in ("measured", "expected"):
                        line[k].append(None)
                    line["t"].append(0.5 * (last_end[name] + start))
                step = s["step"]
                line["t"] += [round(start + (i + 0.5) * step, 6) for i in range(len(s["measured"]))]
                line["measured"] += [_short(v) for v in s["measured"]]
                line["expected"] += [_short(v) for v in s["expected"]]
                last_end[name] = end
        return out


def _short(value: float) -> float:
    """A float32 off the wire as 6 significant digits (its precision; the page's JSON stays short)."""
    return float(f"{value:.6g}")
