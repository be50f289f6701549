"""Healthy reference models, one per sensor, and their one-step-ahead prediction errors.

A reference model predicts a sensor one step ahead from the valve command and the sensor's own
past (Box-Jenkins, Eq. 3.26; NARX series-parallel, Eq. 4.18). Its prediction error
``e(t) = y(t) - ŷ(t|θ)`` (Eq. 5.1) is what the health model turns into verdicts.

Two ways to get the errors, with identical results (tested):

* batch, :meth:`SensorReference.errors` over a whole recording (training, ``hydrowatch score``);
* streaming, :meth:`SensorReference.step` chunk by chunk for M machines at once (the scorer):
  each machine carries a small state (NARX: the last ``delay`` samples of u and y; Box-Jenkins:
  the two IIR filter states), and all machines whose chunks have the same length are stacked into
  one batched call.

The first ``warmup`` samples of a stream have no trustworthy prediction (delay lines filling,
filters starting from rest): their errors are NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.signal import lfilter

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.sysid import NARX, BoxJenkins
from hydrowatch.sysid.polynomials import delayed_numerator, monic

KINDS = ("narx", "bj")
BJ_WARMUP = 100
"""Samples a Box-Jenkins predictor runs from rest before its errors count (0.5 s at 200 Hz)."""


@dataclass
class StreamState:
    """Per machine and sensor: what the predictor needs from the past.

    Attributes
    ----------
    a, b : ndarray
        NARX: last ``delay`` samples of u and y (raw units, oldest first, NaN before the stream).
        Box-Jenkins: states of the filters q^-K B/F and D/C (normalised units).
    seen : int
        Samples fed since the stream (re)started.
    """

    a: np.ndarray
    b: np.ndarray
    seen: int = 0


class SensorReference:
    """The healthy reference model of one sensor (input: valve voltage [V]).

    Parameters
    ----------
    kind : {"narx", "bj"}
    sensor : str
        ``flow`` [L/min], ``speed`` [rad/s] or ``torque`` [N·m].
    params : dict, optional
        Keyword parameters of :class:`~hydrowatch.sysid.NARX` or :class:`~hydrowatch.sysid.BoxJenkins`.
    """

    def __init__(self, *, kind: str = "narx", sensor: str = "speed", params: dict[str, Any] | None = None) -> None:
        self.kind = kind
        self.sensor = sensor
        self.params = params

    def fit(self, u: np.ndarray, y: np.ndarray) -> SensorReference:
        """Fit the model on healthy data ``u`` [V], ``y`` (sensor unit), shape (n,); returns self."""
        if self.kind not in KINDS:
            raise ParameterError(f"reference model kind must be one of {KINDS}. Got {self.kind!r}.")
        params = dict(self.params or {})
        self.model_ = NARX(**params).fit(u, y) if self.kind == "narx" else BoxJenkins(**params).fit(u, y)
        self._prepare()
        return self

    def _prepare(self) -> None:
        m = self.model_
        if isinstance(m, NARX):
            self.warmup_ = int(m.delay)
            return
        gain = m.output_scale_ / m.input_scale_
        self._bf = (delayed_numerator(np.asarray(m.b_) / gain, int(m.delay)), monic(m.f_))
        self._dc = (monic(m.d_), monic(m.c_))
        self.warmup_ = BJ_WARMUP

    # -- batch ----------------------------------------------------------------------------------
    def errors(self, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """One-step prediction errors y - ŷ (Eq. 5.1), shape (n,); NaN for the first ``warmup_`` samples."""
        state = self.initial_state()
        e, _ = self.step(np.asarray(u, dtype=np.float64)[None, :], np.asarray(y, dtype=np.float64)[None, :], [state])
        return e[0]

    # -- streaming ------------------------------------------------------------------------------
    def initial_state(self) -> StreamState:
        """The state of a stream that has seen nothing."""
        m = self.model_
        if isinstance(m, NARX):
            return StreamState(np.full(m.delay, np.nan), np.full(m.delay, np.nan))
        return StreamState(np.zeros(max(len(x) for x in self._bf) - 1), np.zeros(max(len(x) for x in self._dc) - 1))

    def step(self, u: np.ndarray, y: np.ndarray, states: list[StreamState]) -> tuple[np.ndarray, list[StreamState]]:
        """Prediction errors of the next chunk of M machines at once.

        Parameters
        ----------
        u, y : ndarray, shape (M, n)
            Valve command [V] and sensor (its unit), the next n samples of each machine.
        states : list of StreamState, length M
            Each machine's state before the chunk (not modified).

        Returns
        -------
        errors : ndarray, shape (M, n)
            NaN while a stream is warming up.
        states : list of StreamState
            The states after the chunk.
        """
        if u.shape != y.shape or u.ndim != 2 or u.shape[0] != len(states):
            raise DataError(f"u and y must both have shape (M, n) with M = {len(states)}. Got {u.shape}, {y.shape}.")
        if isinstance(self.model_, NARX):
            e, new = self._step_narx(u, y, states)
        else:
            e, new = self._step_bj(u, y, states)
        n = u.shape[1]
        for i, (old, s) in enumerate(zip(states, new)):
            cold = self.warmup_ - old.seen
            if cold > 0:
                e[i, : min(cold, n)] = np.nan
            s.seen = old.seen + n
        return e, new

    def _step_narx(self, u: np.ndarray, y: np.ndarray, states: list[StreamState]) -> tuple[np.ndarray, list]:
        m: NARX = self.model_
        d, n_y, n_u = int(m.delay), int(m.output_delays), int(m.input_delays)
        big_u = np.concatenate([np.stack([s.a for s in states]), u], axis=1)  # (M, d + n)
        big_y = np.concatenate([np.stack([s.b for s in states]), y], axis=1)
        n = u.shape[1]
        # row t (0..n-1) predicts sample d + t from y(d+t-1..d+t-n_y), u(d+t-1..d+t-n_u): Eq. 4.18 layout
        lines = []
        if n_y:
            lines.append(sliding_window_view(big_y[:, d - n_y : d + n - 1], n_y, axis=1)[:, :, ::-1])
        lines.append(sliding_window_view(big_u[:, d - n_u : d + n - 1], n_u, axis=1)[:, :, ::-1])
        regressors = np.concatenate(lines, axis=2).reshape(-1, n_y + n_u)
        predicted = m.one_step(regressors).reshape(u.shape)
        new = [StreamState(big_u[i, -d:].copy(), big_y[i, -d:].copy()) for i in range(len(states))]
        return y - predicted, new

    def _step_bj(self, u: np.ndarray, y: np.ndarray, states: list[StreamState]) -> tuple[np.ndarray, list]:
        m: BoxJenkins = self.model_
        un = (u - m.input_mean_) / m.input_scale_
        yn = (y - m.output_mean_) / m.output_scale_
        # Eq. 3.26: ŷ = y - D/C (y - q^-K B/F u)  =>  e = D/C (y - q^-K B/F u), normalised units
        w, zw = lfilter(*self._bf, un, axis=1, zi=np.stack([s.a for s in states]))
        v, zv = lfilter(*self._dc, yn - w, axis=1, zi=np.stack([s.b for s in states]))
        new = [StreamState(zw[i].copy(), zv[i].copy()) for i in range(len(states))]
        return v * m.output_scale_, new

    # -- description and files ------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        """JSON-able description: NARX network summary, or the Box-Jenkins identify object."""
        return self.model_.summary() if isinstance(self.model_, NARX) else self.model_.to_dict()

    @property
    def nrmse_one_step_(self) -> float:
        """RMS of the training one-step errors / std of the training output."""
        if isinstance(self.model_, NARX):
            return float(self.model_.train_summary_["nrmse_one_step"])
        return float(self.model_.nrmse_one_step_)

    def file_name(self) -> str:
        """File name of the model inside a bundle's ``reference/`` folder."""
        return f"{self.sensor}.{'narx.pt' if self.kind == 'narx' else 'bj.json'}"

    def save(self, folder: str | Path) -> Path:
        """Write the fitted model into ``folder``; returns the file."""
        path = Path(folder) / self.file_name()
        self.model_.save(path)
        return path

    @classmethod
    def load(cls, folder: str | Path, sensor: str, kind: str) -> SensorReference:
        """Read the model of ``sensor`` written by :meth:`save`."""
        ref = cls(kind=kind, sensor=sensor)
        path = Path(folder) / ref.file_name()
        if not path.is_file():
            raise DataError(f"a model bundle must hold reference/{ref.file_name()}. Got none.", str(folder))
        ref.model_ = NARX.load(path) if kind == "narx" else BoxJenkins.load(path)
        ref.params = ref.model_.get_params()
        ref._prepare()
        return ref
