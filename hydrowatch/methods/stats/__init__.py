"""A deliberately simple baseline: per-window statistics of the raw signals and a logistic regression.

Each window of the command and the sensors (``plan.window`` samples, not overlapping) gives the mean,
standard deviation, minimum and maximum of every channel; standardised, they feed a multinomial
logistic regression (scikit-learn for the fit, NumPy for the verdicts). ``kl`` holds, per sensor and
state, the RMS distance of the sensor's standardised statistics to the state's mean (0: typical of
that state). No open-set rule: every valid window is named a trained state. The last 15 % of every
run is held out for the evaluation. Bundle folder: ``stats/model.json``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from hydrowatch.health.metrics import confusion_matrix, expected_calibration_error, per_class_recall
from hydrowatch.health.windows import sliding_windows, window_starts
from hydrowatch.methods.base import HealthMethod, MethodFit, OfflineScores, data_summary, ordered_states, shared_sensors
from hydrowatch.recording import INPUT, Recording
from hydrowatch.verdict import INVALID, Verdict

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings

HELD_OUT = 0.15
"""Share of every run's samples held out for the test windows."""


def window_statistics(raw: np.ndarray) -> np.ndarray:
    """Mean, std, min, max of every channel of windows (m, window, c) → (m, 4c), channel-major."""
    stats = np.stack([raw.mean(axis=1), raw.std(axis=1), raw.min(axis=1), raw.max(axis=1)], axis=2)
    return stats.reshape(raw.shape[0], -1)


def recording_windows(recording: Recording, channels: list[str], window: int) -> np.ndarray:
    """Non-overlapping windows (m, window, c) of a recording's ``channels`` from its first sample."""
    return np.stack([sliding_windows(recording[c], window, window) for c in channels], axis=2)


class StatsMethod(HealthMethod):
    """Fitted baseline (module docstring); ``model`` holds ``mean``, ``scale``, ``coef``, ``intercept``,
    ``centroids`` (n_states, 4c), ``states``, ``channels``, ``window``."""

    name: ClassVar[str] = "stats"

    def __init__(self, model: dict[str, Any]) -> None:
        self.stats = {k: np.asarray(v) if k in ("mean", "scale", "coef", "intercept", "centroids") else v
                      for k, v in model.items()}

    @classmethod
    def fit(cls, grouped: Mapping[str, list[Recording]], settings: TrainingSettings) -> MethodFit:
        """Windows of every run (the last :data:`HELD_OUT` tested), statistics, logistic regression."""
        from sklearn.linear_model import LogisticRegression

        states, window = ordered_states(list(grouped)), settings.plan.window
        channels = [INPUT, *shared_sensors(grouped)]
        fit: dict[str, list[np.ndarray]] = {s: [] for s in states}
        test: dict[str, list[np.ndarray]] = {s: [] for s in states}
        for s in states:
            for run in grouped[s]:
                cut = len(run) - int(round(HELD_OUT * len(run)))
                for part, into in ((run.slice(0, cut), fit), (run.slice(cut, len(run)), test)):
                    if len(part) >= window:
                        into[s].append(window_statistics(recording_windows(part, channels, window)))
        x = np.concatenate([np.concatenate(fit[s]) for s in states])
        y = np.concatenate([np.full(sum(len(f) for f in fit[s]), i) for i, s in enumerate(states)])
        mean, scale = x.mean(axis=0), np.where(x.std(axis=0) > 0, x.std(axis=0), 1.0)
        z = (x - mean) / scale
        lr = LogisticRegression(max_iter=1000, random_state=settings.seed).fit(z, y)
        centroids = np.stack([z[y == i].mean(axis=0) for i in range(len(states))])
        method = cls({"mean": mean, "scale": scale, "coef": lr.coef_, "intercept": lr.intercept_,
                      "centroids": centroids, "states": states, "channels": channels, "window": window})
        xt = {s: np.concatenate(test[s]) if test[s] else np.empty((0, x.shape[1])) for s in states}
        evaluation = method._evaluate(xt)
        manifest = {"method": cls.name, "reference": None, "states": states, "sensors": channels[1:],
                    "window": window, "hop": window, "warmup": 0, "settings": settings.to_dict(),
                    "data": data_summary(grouped, states), "metrics": {"test_accuracy": evaluation["test_accuracy"]}}
        return MethodFit(method, manifest, {s: method._judge(xt[s])[1] for s in states}, evaluation)

    @classmethod
    def settings_dict(cls, settings: TrainingSettings) -> dict[str, Any]:
        """``method`` and ``seed``."""
        return {"method": cls.name, "seed": settings.seed}

    @classmethod
    def load(cls, directory: Path, manifest: Mapping[str, Any]) -> StatsMethod:
        """``stats/model.json`` under ``directory``."""
        return cls(json.loads((directory / "stats" / "model.json").read_text()))

    def save(self, directory: Path) -> list[Path]:
        """``stats/model.json`` under ``directory``."""
        (directory / "stats").mkdir(parents=True, exist_ok=True)
        path = directory / "stats" / "model.json"
        path.write_text(json.dumps({k: np.asarray(v).tolist() for k, v in self.stats.items()}))
        return [path]

    headline = property(lambda self: "Window statistics + logistic regression (baseline)")
    sensors = property(lambda self: list(self.stats["channels"][1:]))
    channels = property(lambda self: list(self.stats["channels"]))
    states = property(lambda self: list(self.stats["states"]))
    window = property(lambda self: int(self.stats["window"]))
    hop = window

    def _judge(self, x: np.ndarray) -> tuple[list[Verdict], np.ndarray]:
        """Verdicts and ``kl`` distances (m, n_sensors, n_states) of window statistics x (m, 4c)."""
        m, st = self.stats, self.states
        z = (x - m["mean"]) / m["scale"]
        logits = z @ m["coef"].T + m["intercept"]
        logits = np.column_stack([np.zeros(len(z)), logits]) if logits.shape[1] == 1 else logits
        p = np.exp(logits - logits.max(axis=1, keepdims=True))
        p /= p.sum(axis=1, keepdims=True)
        gap = (z[:, None, :] - m["centroids"][None]).reshape(len(z), len(st), len(self.channels), 4)[:, :, 1:]
        kl = np.sqrt(np.mean(gap**2, axis=3)).transpose(0, 2, 1)
        verdicts = [Verdict(st[int(np.argmax(q))], float(q.max()), dict(zip(st, map(float, q))))
                    if np.all(np.isfinite(row)) else Verdict(INVALID, None, {}, "NaN in the window")
                    for row, q in zip(z, p)]
        return verdicts, kl

    def _evaluate(self, test: Mapping[str, np.ndarray]) -> dict[str, Any]:
        truth = np.concatenate([np.full(len(test[s]), s) for s in self.states])
        verdicts = self._judge(np.concatenate([test[s] for s in self.states]))[0]
        ok = np.array([v.state != INVALID for v in verdicts])
        y, judged = truth[ok], np.array([v.state for v in verdicts])[ok]
        p = np.array([[v.probabilities[s] for s in self.states] for v, k in zip(verdicts, ok) if k])
        accuracy = float(np.mean(judged == y))
        return {"test_accuracy": accuracy, "test_accuracy_with_open_set": accuracy, "known_rejected": 0.0,
                "per_class_recall": per_class_recall(y, judged, self.states), "labels": self.states,
                "confusion_matrix": confusion_matrix(y, judged, self.states).tolist(), "test_windows": int(y.size),
                "ece": expected_calibration_error(p, np.array([self.states.index(s) for s in y]))}

    def score(self, recording: Recording, smoothing: int = 1) -> OfflineScores:
        """Non-overlapping windows from the first sample; ``kl``: distances to each state's statistics."""
        verdicts, kl = self._judge(window_statistics(recording_windows(recording, self.channels, self.window)))
        return OfflineScores(window_starts(len(recording), self.window, self.window), verdicts, kl)

    def online(self, *, smoothing: int = 1,
               unit_method: Callable[[str], HealthMethod | None] | None = None) -> _Judge:
        """A :class:`~hydrowatch.methods.base.WindowJudge` of raw windows of :attr:`channels`."""
        return _Judge(self)


class _Judge:
    def __init__(self, method: StatsMethod) -> None:
        self.method, self.columns, self.defaults = method, method.channels, dict[str, float]()
        self.window = self.hop = method.window

    def judge(self, raw: np.ndarray, machines: Any) -> list[tuple[Verdict, np.ndarray]]:
        verdicts, kl = self.method._judge(window_statistics(raw))
        return list(zip(verdicts, kl))
