"""The health model: base distributions + classifier + open-set rule, fitted and stored together.

``fit`` follows the study's procedure (Figure 6.4, section 6.3): base distributions from each
state's base part of the data plan, feature vectors of each state's classifier windows, the
classifier on those (70/15/15), and the open-set rule calibrated on the classifier's train and
validation windows. ``save``/``load`` use one directory with three small files
(``base_distributions.json``, ``classifier.npz``, ``open_set.json``), no pickle.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.errors import DataError, NotFittedError
from hydrowatch.health.classifier import HealthClassifier, labelled_rows
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.health.metrics import accuracy, confusion_matrix
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.health.verdict import judge
from hydrowatch.recording import SENSORS
from hydrowatch.verdict import UNKNOWN, Verdict

FILES = {"features": "base_distributions.json", "classifier": "classifier.npz", "open_set": "open_set.json"}


def _clone(estimator: Any) -> Any:
    return type(estimator)(**estimator.get_params())


class HealthModel:
    """Everything needed to turn prediction errors into verdicts.

    Parameters
    ----------
    features : RelativeEntropyFeatures, optional
        Unfitted template (its parameters are used); default ``RelativeEntropyFeatures()``.
    classifier : HealthClassifier, optional
        Unfitted template; default ``HealthClassifier()``.
    open_set : OpenSetRule, optional
        Unfitted template; default ``OpenSetRule()``.

    Attributes
    ----------
    features_, classifier_, open_set_
        The fitted parts.
    report_ : dict
        Test accuracy, confusion matrix (true rows), ECE, and the share of known test windows the
        open-set rule rejects.
    """

    def __init__(
        self,
        *,
        features: RelativeEntropyFeatures | None = None,
        classifier: HealthClassifier | None = None,
        open_set: OpenSetRule | None = None,
    ) -> None:
        self.features = features
        self.classifier = classifier
        self.open_set = open_set

    def fit(
        self,
        base_errors: Mapping[str, np.ndarray],
        window_errors: Mapping[str, np.ndarray],
        sensors: Sequence[str] = SENSORS,
    ) -> HealthModel:
        """Fit all parts; returns self.

        Parameters
        ----------
        base_errors : mapping of state to ndarray, shape (n_k, n_sensors)
            Prediction errors of each state's base part (40,000 samples in the study).
        window_errors : mapping of state to ndarray, shape (m_k, n_sensors)
            Prediction errors of each state's classifier part (200 windows in the study). Same states.
        """
        if set(window_errors) != set(base_errors):
            raise DataError(
                f"window_errors must have the same states as base_errors. Got {sorted(window_errors)} "
                f"and {sorted(base_errors)}."
            )
        self.features_ = _clone(self.features or RelativeEntropyFeatures()).fit(base_errors, sensors)
        states = list(self.features_.states_)
        X, y = labelled_rows({s: self.features_.transform(window_errors[s]) for s in states})
        self.classifier_ = _clone(self.classifier or HealthClassifier()).fit(X, y, classes=states)
        split = self.classifier_.split_
        calibration = np.concatenate([split["train"], split["validation"]])
        self.open_set_ = _clone(self.open_set or OpenSetRule()).fit(X[calibration], y[calibration], states)
        test = split["test"]
        pred = self.classifier_.predict(X[test])
        pred[self.open_set_.is_unknown(X[test], self.classifier_.predict_proba(X[test]))] = UNKNOWN
        self.report_ = {
            "test_accuracy": self.classifier_.test_accuracy_,
            "test_accuracy_with_open_set": accuracy(y[test], pred),
            "known_rejected": float(np.mean(pred == UNKNOWN)) if test.size else float("nan"),
            "confusion_matrix": self.classifier_.confusion_matrix_.tolist(),
            "confusion_matrix_with_open_set": confusion_matrix(y[test], pred, [*states, UNKNOWN]).tolist(),
            "ece": self.classifier_.ece_,
            "ece_uncalibrated": self.classifier_.ece_uncalibrated_,
            "temperature": self.classifier_.temperature_,
            "states": states,
            "windows": int(X.shape[0]),
        }
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "classifier_"):
            raise NotFittedError("HealthModel must be fitted before use. Call fit(...) or HealthModel.load(dir).")

    def score(self, errors: np.ndarray) -> tuple[np.ndarray, list[Verdict]]:
        """Window starts (sample index, shape (n_windows,)) and verdicts of one machine's errors (n, n_sensors)."""
        self._check_fitted()
        features = self.features_.transform(errors)
        reasons = self.features_.window_reasons(errors)
        return self.features_.window_starts(np.asarray(errors).shape[0]), judge(
            features, self.classifier_, self.open_set_, reasons
        )

    def save(self, directory: str | Path) -> None:
        """Write the three parts into ``directory`` (created if missing)."""
        self._check_fitted()
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.features_.save(d / FILES["features"])
        self.classifier_.save(d / FILES["classifier"])
        (d / FILES["open_set"]).write_text(json.dumps(self.open_set_.to_dict(), indent=1))

    @classmethod
    def load(cls, directory: str | Path) -> HealthModel:
        """Read a directory written by :meth:`save`."""
        d = Path(directory)
        missing = [name for name in FILES.values() if not (d / name).is_file()]
        if missing:
            raise DataError(f"a health model directory must hold {sorted(FILES.values())}. Missing {missing}.", str(d))
        model = cls()
        model.features_ = RelativeEntropyFeatures.load(d / FILES["features"])
        model.classifier_ = HealthClassifier.load(d / FILES["classifier"])
        try:
            model.open_set_ = OpenSetRule.from_dict(json.loads((d / FILES["open_set"]).read_text()))
        except json.JSONDecodeError as exc:
            raise DataError(f"open_set.json must be valid JSON. Got: {exc}.", str(d)) from None
        return model
