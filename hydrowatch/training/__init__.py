"""Training and scoring wiring: reference models (sysid) + health model (health) → model bundles.

See docs/health-pipeline.md. :func:`train` fits a :class:`ModelBundle` from labelled recordings
(:func:`read_labelled`); :func:`score_recording` gives the contract's ``score --json`` objects;
:class:`OnlineScorer` does the same window by window for a fleet on the bus;
:func:`log_training` tracks a run in MLflow and registers the bundle. Names are imported on first
use, so ``hydrowatch`` commands that only parse flags stay quick to start.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "DEMO_PLAN": "options", "TrainingSettings": "options",
    "ModelBundle": "bundle", "load_bundle": "bundle",
    "read_labelled": "data", "recording_files": "data",
    "SensorReference": "reference",
    "pooled_accuracy": "scoring", "score_recording": "scoring",
    "log_training": "tracking", "tracking_uri": "tracking",
    "train": "trainer",
    "Chunk": "online", "OnlineScorer": "online", "WindowVerdict": "online",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'hydrowatch.training' has no attribute {name!r}")
    return getattr(importlib.import_module(f"hydrowatch.training.{_EXPORTS[name]}"), name)
