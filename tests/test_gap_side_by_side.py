"""Independent steps of an analysis run side by side (issue 12, item 5: "under 5 minutes on 2 cores")."""

from __future__ import annotations

import threading

import pytest

from hydrowatch.gap.side_by_side import side_by_side


def test_steps_run_at_the_same_time_on_two_threads_and_one_after_the_other_on_one(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYDROWATCH_THREADS", "2")
    meet = threading.Barrier(2, timeout=10.0)  # broken (an error) unless both steps wait at once

    def step(value: int) -> tuple[int, str]:
        meet.wait()
        return value, threading.current_thread().name

    done = side_by_side([lambda: step(1), lambda: step(2)])
    assert [v for v, _ in done] == [1, 2] and done[0][1] != done[1][1]
    monkeypatch.setenv("HYDROWATCH_THREADS", "1")
    ran: list[int] = []
    assert side_by_side([lambda: ran.append(1) or 1, lambda: ran.append(2) or 2]) == [1, 2]
    assert ran == [1, 2]


def test_a_failing_step_raises_its_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYDROWATCH_THREADS", "2")

    def fails() -> int:
        raise ValueError("step failed")

    with pytest.raises(ValueError, match="step failed"):
        side_by_side([lambda: 1, fails])
