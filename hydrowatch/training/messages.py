"""Bus messages of the scorer: ``kl_window``, ``health_verdict``, ``forecast`` and ``expected_window`` record batches
(schemas/)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyarrow as pa

from hydrowatch.channels import PLANT
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.schemas import EXPECTED_WINDOW, FORECAST, HEALTH_VERDICT, KL_WINDOW, wire_schema
from hydrowatch.training.forecasts import MachineForecast
from hydrowatch.training.online import WindowVerdict
from hydrowatch.verdict import INVALID, UNKNOWN

OPEN_SET_REASON = "no trained state explains the window (open-set rule)"


def verdict_batch(item: WindowVerdict, model_version: str) -> pa.RecordBatch:
    """One ``health_verdict`` (v2) row; ``probability`` is 0 for ``invalid`` and ``unknown``; ``degradation`` null when
    the window has none."""
    v = item.verdict
    reason = v.reason if v.reason is not None else (OPEN_SET_REASON if v.state == UNKNOWN else None)
    row = {
        "window_start": [item.start_s], "window_end": [item.end_s], "state": [v.state],
        "probability": [float(v.probability) if v.probability is not None else 0.0],
        "probabilities": [[{"state": s, "probability": float(p)} for s, p in v.probabilities.items()]],
        "reason": [reason], "model_version": [model_version],
        "degradation": [None if item.degradation is None else [
            {"fault": f, "index": float(d["value"]), "low": float(d["ci95"][0]), "high": float(d["ci95"][1])}
            for f, d in item.degradation.items() if not d.get("provisional", False)]],
    }
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(HEALTH_VERDICT))


def kl_batch(
    item: WindowVerdict, sensors: Sequence[str], states: Sequence[str], model_version: str
) -> pa.RecordBatch | None:
    """The ``kl_window`` rows (sensor × state) of a judged window; None when it has no finite scores.

    ``sensors`` are the bundle's ``kl_rows``: sensors for the entropy method (``relative_entropy``
    in nats), relations (``load``, ``motor``, ``valve``) for the parity method (``relative_entropy``
    then carries the relation score F[r, k], dimensionless, ≥ 1).
    """
    d = item.scores
    if d is None or item.verdict.state == INVALID or not np.all(np.isfinite(d)):
        return None
    n = len(sensors) * len(states)
    row = {
        "window_start": [item.start_s] * n, "window_end": [item.end_s] * n,
        "sensor": [s for s in sensors for _ in states], "state": [k for _ in sensors for k in states],
        "relative_entropy": np.asarray(d, dtype=np.float64).reshape(-1).tolist(), "model_version": [model_version] * n,
    }
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(KL_WINDOW))


def forecast_batch(item: MachineForecast, model_version: str) -> pa.RecordBatch:
    """The ``forecast`` rows of one machine, one per part (:meth:`Forecast.to_dict
    <hydrowatch.condition.forecast.Forecast.to_dict>`'s values; non-finite numbers as null)."""
    parts = [(fault, f.to_dict()) for fault, f in item.parts.items()]
    n = len(parts)
    row = {
        "window_start": [item.start_s] * n, "fault": [fault for fault, _ in parts],
        "alert_in_s": [d["alert_in_s"] for _, d in parts],
        "low_s": [d["ci95"][0] for _, d in parts], "high_s": [d["ci95"][1] for _, d in parts],  # type: ignore[index]
        "rate_per_h": [d["rate_per_h"] for _, d in parts], "level": [d["level"] for _, d in parts],
        "model": [d["model"] for _, d in parts], "points": [d["points"] for _, d in parts],
        "reset_at": [d["reset_at_s"] for _, d in parts], "reason": [d.get("reason") for _, d in parts],
        "untold_from": [d.get("untold_from") for _, d in parts],
        "history_windows": [item.history_windows] * n, "model_version": [model_version] * n,
    }
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(FORECAST))


def expected_batch(item: WindowVerdict, model_version: str) -> pa.RecordBatch | None:
    """The ``expected_window`` rows (one per sensor the model predicts) of a judged window; None when it has none
    (an invalid window, a method that predicts no sensor, or a scorer not asked for them)."""
    found = item.expected
    if not found or item.verdict.state == INVALID:
        return None
    sensors = list(found)
    n = len(sensors)
    row = {
        "window_start": [item.start_s] * n, "window_end": [item.end_s] * n, "sensor": sensors,
        "unit": [PLANT.units.get(s, "") for s in sensors],
        "step": [found[s].step / SAMPLE_RATE_HZ for s in sensors],
        "measured": [np.asarray(found[s].measured, dtype=np.float32) for s in sensors],
        "expected": [np.asarray(found[s].expected, dtype=np.float32) for s in sensors],
        "source": [found[s].source for s in sensors], "model_version": [model_version] * n,
    }
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(EXPECTED_WINDOW))
