"""The trainer: labelled recordings in, a model bundle and its evaluation out (study Figure 6.4).

:func:`train` asks the method named by ``settings.method`` (:mod:`hydrowatch.methods`) to fit itself,
and wraps what it returns into a :class:`~hydrowatch.training.bundle.ModelBundle` and a
:class:`~hydrowatch.results.TrainingResult`. The methods' own steps are in their packages
(:mod:`hydrowatch.methods.entropy.train`, :mod:`hydrowatch.methods.parity.train`, …).
"""

from __future__ import annotations

import time
from collections.abc import Mapping

from hydrowatch.errors import DataError
from hydrowatch.methods import method_class
from hydrowatch.methods.base import HEALTHY
from hydrowatch.recording import Recording
from hydrowatch.results import TrainingResult
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.options import TrainingSettings


def train(grouped: Mapping[str, list[Recording]], settings: TrainingSettings | None = None) -> TrainingResult:
    """Train a model bundle from recordings grouped by health state (:func:`~hydrowatch.training.data.read_labelled`).

    Raises
    ------
    DataError
        When ``healthy`` is missing or a state has fewer samples than the method needs.
    """
    settings = settings or TrainingSettings()
    start = time.perf_counter()
    if HEALTHY not in grouped:
        raise DataError(f"training data must include the '{HEALTHY}' state. Got {sorted(grouped)}.")
    fitted = method_class(settings.method).fit(grouped, settings)
    bundle = ModelBundle(fitted.method, fitted.manifest)
    return TrainingResult(bundle, fitted.base_errors, fitted.window_scores, fitted.evaluation, fitted.reference,
                          time.perf_counter() - start)
