"""The classification network that fuses the sensors' relative entropies (study sections 5.4.4-5.4.5, 6.5).

Architecture (Figure 5.17, Table 6.2): inputs = the window's relative entropies (21 for 7 states
and 3 sensors), one hidden layer of log-sigmoid neurons (Eq. 5.4, 15 by default), a softmax
output layer (Eq. 5.5) with one output per health state. Training (torch, CPU): cross-entropy,
full-batch Adam, the data split 70/15/15 per state (Table 6.3); early stopping on the validation
cross-entropy (``patience`` epochs without an improvement of ``tol``, best weights restored; the study stops
when validation accuracy stops improving, the cross-entropy is the finer signal). Afterwards the
outputs are calibrated by temperature scaling on the validation split (Guo et al. 2017): the
logits are divided by one scalar ``T`` that minimises the validation cross-entropy, which changes
the probabilities but never the predicted state. The test split gives accuracy, confusion matrix
and expected calibration error.

Prediction runs in numpy (no torch import needed to score): a forward pass is two small matrix
products.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.features import log_features
from hydrowatch.health.metrics import accuracy, confusion_matrix, expected_calibration_error
from hydrowatch.log import event, get_logger

_log = get_logger(__name__)
_ARRAYS = ("W1_", "b1_", "W2_", "b2_", "feature_mean_", "feature_scale_")


def labelled_rows(blocks: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Feature rows of every state stacked with their labels, non-finite rows (invalid windows) dropped.

    Parameters
    ----------
    blocks : mapping of state to ndarray, shape (m_k, n_features)
        Each state's feature rows, in the order the states should appear.

    Returns
    -------
    X : ndarray, shape (n, n_features)
    y : ndarray of str, shape (n,)
    """
    X = np.concatenate(list(blocks.values()))
    y = np.repeat(np.asarray(list(blocks)), [b.shape[0] for b in blocks.values()])
    valid = np.all(np.isfinite(X), axis=1)
    return X[valid], y[valid]


def stratified_split(
    y: np.ndarray, fractions: Sequence[float] = (0.70, 0.15, 0.15), seed: int = 0
) -> dict[str, np.ndarray]:
    """Indices of the train, validation and test parts, the same fractions within every state.

    Each state's windows are shuffled (``seed``) and cut at ``fractions``; e.g. 200 windows give
    140/30/30. Returns ``{"train": idx, "validation": idx, "test": idx}`` (sorted).
    """
    f = np.asarray(fractions, dtype=np.float64)
    if f.shape != (3,) or np.any(f < 0) or not np.isclose(f.sum(), 1.0) or f[0] == 0 or f[1] == 0:
        raise ParameterError(
            f"split must be three fractions (train>0, validation>0, test>=0) summing to 1. Got {fractions}."
        )
    rng = np.random.default_rng(seed)
    parts: dict[str, list[np.ndarray]] = {"train": [], "validation": [], "test": []}
    for label in np.unique(y):
        idx = rng.permutation(np.flatnonzero(y == label))
        n_train = int(round(f[0] * idx.size))
        n_val = int(round(f[1] * idx.size))
        parts["train"].append(idx[:n_train])
        parts["validation"].append(idx[n_train : n_train + n_val])
        parts["test"].append(idx[n_train + n_val :])
    return {k: np.sort(np.concatenate(v)) for k, v in parts.items()}


class HealthClassifier:
    """Health state classifier on relative-entropy feature vectors (scikit-learn conventions).

    Parameters
    ----------
    hidden : int, default 15
        Log-sigmoid neurons (Table 6.2).
    log_features : bool, default True
        Feed ``log(max(D, 1e-6))`` instead of ``D`` (measured better, docs/health.md).
    split : tuple of 3 floats, default (0.70, 0.15, 0.15)
        Train, validation and test fractions (Table 6.3), per state.
    max_epochs : int, default 3000
    patience : int, default 100
        Epochs without a validation cross-entropy better by ``tol`` before stopping.
    learning_rate : float, default 0.01
        Adam step size.
    tol : float, default 1e-4
        Smallest decrease of the validation cross-entropy (nats) that counts as better.
    calibrate : bool, default True
        Temperature scaling on the validation split.
    random_state : int, default 0
        Seed of the split and of the initial weights.

    Attributes
    ----------
    classes_ : ndarray of str, shape (n_states,)
    split_ : dict of str to ndarray
        Row indices of the train, validation and test parts.
    temperature_ : float
    n_epochs_, best_epoch_ : int
    test_accuracy_ : float
    confusion_matrix_ : ndarray, shape (n_states, n_states)
        On the test split, true state on rows.
    ece_, ece_uncalibrated_ : float
        Expected calibration error on the test split, with and without temperature scaling.
    """

    def __init__(
        self,
        *,
        hidden: int = 15,
        log_features: bool = True,
        split: tuple[float, float, float] = (0.70, 0.15, 0.15),
        max_epochs: int = 3000,
        patience: int = 100,
        learning_rate: float = 0.01,
        tol: float = 1e-4,
        calibrate: bool = True,
        random_state: int = 0,
    ) -> None:
        self.hidden = hidden
        self.log_features = log_features
        self.split = split
        self.max_epochs = max_epochs
        self.patience = patience
        self.learning_rate = learning_rate
        self.tol = tol
        self.calibrate = calibrate
        self.random_state = random_state

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {k: getattr(self, k) for k in ("hidden", "log_features", "split", "max_epochs", "patience",
                                              "learning_rate", "tol", "calibrate", "random_state")}

    def _inputs(self, X: np.ndarray) -> np.ndarray:
        x = np.asarray(X, dtype=np.float64)
        return log_features(x) if self.log_features else x

    def fit(
        self, X: np.ndarray, y: Sequence[str] | np.ndarray, classes: Sequence[str] | None = None
    ) -> HealthClassifier:
        """Train on feature vectors ``X`` (n, n_features) with states ``y`` (n,); returns self.

        ``classes`` fixes the output order (default: sorted unique ``y``). Rows with NaN are refused.
        """
        import torch

        if self.hidden < 1 or self.max_epochs < 1 or self.patience < 1 or not self.learning_rate > 0:
            raise ParameterError(
                f"hidden, max_epochs, patience must be >= 1 and learning_rate > 0. Got {self.hidden}, "
                f"{self.max_epochs}, {self.patience}, {self.learning_rate}."
            )
        x = self._inputs(X)
        labels = np.asarray(y).astype(str)
        if x.ndim != 2 or labels.shape != (x.shape[0],):
            raise DataError(f"X must be (n, n_features) and y (n,). Got {x.shape} and {labels.shape}.")
        if not np.all(np.isfinite(x)):
            raise DataError("X must be finite. Got NaN/inf rows (invalid windows); drop them before fit.")
        self.classes_ = np.asarray(sorted(set(labels.tolist())) if classes is None else list(classes), dtype=str)
        missing = sorted(set(labels.tolist()) - set(self.classes_.tolist()))
        if missing:
            raise DataError(f"every label in y must be one of classes. Got unknown labels {missing}.")
        column = {c: i for i, c in enumerate(self.classes_.tolist())}
        target = np.array([column[v] for v in labels.tolist()], dtype=np.int64)
        self.split_ = stratified_split(labels, self.split, self.random_state)
        tr, va = self.split_["train"], self.split_["validation"]
        self.feature_mean_ = x[tr].mean(axis=0)
        self.feature_scale_ = np.maximum(x[tr].std(axis=0), 1e-12)
        z = (x - self.feature_mean_) / self.feature_scale_

        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # a 15-neuron network: threads only add contention (50x slower measured)
        try:
            net = self._train(torch, z[tr], target[tr], z[va], target[va])
        finally:
            torch.set_num_threads(threads)
        self.W1_, self.b1_ = net[0].weight.detach().numpy().T.copy(), net[0].bias.detach().numpy().copy()
        self.W2_, self.b2_ = net[2].weight.detach().numpy().T.copy(), net[2].bias.detach().numpy().copy()

        self.temperature_ = 1.0
        if self.calibrate:
            self.temperature_ = fit_temperature(self._logits(z[va]), target[va])
        self._score_test(z, target)
        event(_log, "classifier trained", epochs=self.n_epochs_, best_epoch=self.best_epoch_,
              temperature=round(self.temperature_, 4), test_accuracy=self.test_accuracy_)
        return self

    def _train(self, torch: Any, z_train: np.ndarray, t_train: np.ndarray, z_val: np.ndarray, t_val: np.ndarray) -> Any:
        """Full-batch Adam with early stopping on the validation cross-entropy; the best network."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.random_state)
            net = torch.nn.Sequential(torch.nn.Linear(z_train.shape[1], self.hidden), torch.nn.Sigmoid(),
                                      torch.nn.Linear(self.hidden, len(self.classes_))).double()
        x_tr, y_tr = torch.from_numpy(z_train), torch.from_numpy(t_train)
        x_va, y_va = torch.from_numpy(z_val), torch.from_numpy(t_val)
        opt = torch.optim.Adam(net.parameters(), lr=self.learning_rate)
        loss_fn = torch.nn.CrossEntropyLoss()
        best, best_state, self.best_epoch_, epoch = np.inf, None, 0, 0
        for epoch in range(1, self.max_epochs + 1):
            opt.zero_grad()
            loss = loss_fn(net(x_tr), y_tr)
            loss.backward()
            opt.step()
            with torch.no_grad():
                val = float(loss_fn(net(x_va), y_va))
            if val < best - self.tol:
                best, self.best_epoch_ = val, epoch
                best_state = {k: v.clone() for k, v in net.state_dict().items()}
            elif epoch - self.best_epoch_ >= self.patience:
                break
        self.n_epochs_ = epoch
        if best_state is not None:
            net.load_state_dict(best_state)
        return net

    def _score_test(self, z: np.ndarray, target: np.ndarray) -> None:
        te = self.split_["test"]
        if te.size == 0:
            self.test_accuracy_, self.ece_, self.ece_uncalibrated_ = float("nan"), float("nan"), float("nan")
            self.confusion_matrix_ = np.zeros((len(self.classes_),) * 2, dtype=np.int64)
            return
        logits = self._logits(z[te])
        proba = _softmax(logits / self.temperature_)
        pred = self.classes_[proba.argmax(axis=1)]
        truth = self.classes_[target[te]]
        self.test_accuracy_ = accuracy(truth, pred)
        self.confusion_matrix_ = confusion_matrix(truth, pred, self.classes_.tolist())
        self.ece_ = expected_calibration_error(proba, target[te])
        self.ece_uncalibrated_ = expected_calibration_error(_softmax(logits), target[te])

    def _logits(self, z: np.ndarray) -> np.ndarray:
        hidden = 1.0 / (1.0 + np.exp(-(z @ self.W1_ + self.b1_)))  # Eq. 5.4
        return hidden @ self.W2_ + self.b2_

    def _check_fitted(self) -> None:
        if not hasattr(self, "W1_"):
            raise NotFittedError("HealthClassifier must be fitted before use. Call fit(X, y) or load(path) first.")

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Calibrated probabilities (Eq. 5.5 on logits / T), shape (n, n_states); NaN rows stay NaN."""
        self._check_fitted()
        x = self._inputs(X)
        if x.ndim != 2 or x.shape[1] != self.W1_.shape[0]:
            raise DataError(f"X must have shape (n, {self.W1_.shape[0]}). Got {x.shape}.")
        return _softmax(self._logits((x - self.feature_mean_) / self.feature_scale_) / self.temperature_)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Most probable state per row, shape (n,)."""
        proba = self.predict_proba(X)
        return self.classes_[np.nan_to_num(proba, nan=-1.0).argmax(axis=1)]

    def save(self, path: str | Path) -> None:
        """Write weights and parameters to ``path`` (.npz, no pickle)."""
        self._check_fitted()
        meta = {"params": self.get_params(), "temperature": self.temperature_,
                "test": {"accuracy": self.test_accuracy_, "ece": self.ece_, "ece_uncalibrated": self.ece_uncalibrated_}}
        np.savez(Path(path), classes=self.classes_, meta=np.array(json.dumps(meta)),
                 **{k: getattr(self, k) for k in _ARRAYS})

    @classmethod
    def load(cls, path: str | Path) -> HealthClassifier:
        """Read a file written by :meth:`save`."""
        try:
            with np.load(Path(path), allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                model = cls(**{**meta["params"], "split": tuple(meta["params"]["split"])})
                for k in _ARRAYS:
                    setattr(model, k, data[k])
                model.classes_ = data["classes"]
        except (OSError, KeyError, ValueError) as exc:
            raise DataError(f"classifier file must be an .npz written by HealthClassifier.save. Got: {exc}.",
                            str(path)) from None
        model.temperature_ = float(meta["temperature"])
        model.test_accuracy_ = meta["test"]["accuracy"]
        model.ece_ = meta["test"]["ece"]
        model.ece_uncalibrated_ = meta["test"]["ece_uncalibrated"]
        return model


def _softmax(logits: np.ndarray) -> np.ndarray:
    """Eq. 5.5 along the last axis."""
    shifted = logits - logits.max(axis=-1, keepdims=True)
    e = np.exp(shifted)
    return e / e.sum(axis=-1, keepdims=True)


def fit_temperature(logits: np.ndarray, target: np.ndarray) -> float:
    """Temperature ``T`` in [0.02, 50] minimising the cross-entropy of ``softmax(logits / T)`` against ``target``."""

    def nll(log_t: float) -> float:
        z = logits / np.exp(log_t)
        z = z - z.max(axis=1, keepdims=True)
        return float(np.mean(np.log(np.exp(z).sum(axis=1)) - z[np.arange(z.shape[0]), target]))

    res = minimize_scalar(nll, bounds=(np.log(0.02), np.log(50.0)), method="bounded")
    return float(np.exp(res.x))
