"""The study's search for a NARX structure (section 4.5.2, Tables 4.2-4.6).

1. Delay lines: with the smallest hidden layer, grow the input and output delay lines together
   until the residual autocorrelation (Eq. 4.22) and the input-residual cross-correlation
   (Eq. 4.23) sit inside their confidence bounds (5/5 → 15/15 in the study), or until a longer
   line no longer lowers the held-out error (with a low-pass input, neighbouring lags of the
   cross-correlation move together, so a model at the noise floor can still poke out of the
   bounds at a few lags).
2. Neurons: with those delay lines, grow the hidden layer while the effective number of
   parameters γ (Eq. 4.21) stays close to the parameter count, i.e. the network uses all the
   weights it has (10 → 35 neurons in the study: γ = 301 of 321), and while the held-out error
   still drops ("little decrease in mean square error", Fig. 4.16).

Correlations and errors are measured on a held-out tail of the record, not on the fit data.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.sysid.narx import NARX
from hydrowatch.sysid.narx_lines import check_signals

__all__ = ["search_structure"]

_log = get_logger(__name__)


def _ascending(values: Sequence[int], name: str) -> list[int]:
    out = [int(v) for v in values]
    if not out or any(v < 1 for v in out) or out != sorted(set(out)):
        raise ParameterError(f"{name} must be a non-empty strictly increasing sequence of integers >= 1. "
                             f"Got {tuple(values)!r}.")
    return out


def _evaluate(model: NARX, u: np.ndarray, y: np.ndarray, max_lag: int) -> dict[str, Any]:
    """Held-out checks of a fitted model: correlations inside the bounds and one-step NRMSE."""
    corr = model.residual_correlations(u, y, max_lag=max_lag)
    eps = y[model.delay :] - model.predict(u, y)[model.delay :]
    return {
        "input_delays": model.input_delays, "output_delays": model.output_delays, "hidden": model.hidden,
        "n_parameters": model.n_parameters_, "gamma": float(model.gamma_),
        "acf_inside": corr["acf_inside"], "ccf_inside": corr["ccf_inside"],
        "nrmse_one_step": float(np.sqrt(np.mean(eps**2)) / np.std(y[model.delay :])),
    }


def search_structure(
    u: np.ndarray,
    y: np.ndarray,
    *,
    delays: Sequence[int] = (5, 10, 15, 20),
    hidden: Sequence[int] = (10, 20, 35, 50),
    holdout: float = 0.25,
    max_lag: int = 20,
    min_inside: float = 0.9,
    gamma_ratio: float = 0.85,
    min_improvement: float = 0.02,
    refit: bool = True,
    **narx_params: Any,
) -> tuple[NARX, list[dict[str, Any]]]:
    """Choose delay lines and neurons by the study's rules; returns the model and the search table.

    Parameters
    ----------
    u : ndarray, shape (n,) or (n, n_inputs)
        Input(s), e.g. valve command [V].
    y : ndarray, shape (n,)
        Output, e.g. gearbox speed [rad/s].
    delays : sequence of int
        Candidate delay-line lengths, used for input and output alike, tried in increasing order.
    hidden : sequence of int
        Candidate hidden-layer sizes in increasing order; the first is used while searching delays.
    holdout : float
        Share of the record (its tail) kept for the correlation and error checks, in (0, 0.5].
    max_lag : int
        Lags of the residual correlations (Eqs. 4.22, 4.23).
    min_inside : float
        Share of correlation lags that must lie inside the 95 % bounds for the delay lines to be
        long enough (about 0.95 is expected of white residuals).
    gamma_ratio : float
        The hidden layer grows while γ / n_parameters >= this.
    min_improvement : float
        ... and while each growth lowers the held-out NRMSE by at least this relative amount.
    refit : bool
        Refit the chosen structure on the whole record (else it stays fitted on the head).
    **narx_params
        Further :class:`NARX` parameters (``max_iter``, ``seed``, ...).

    Returns
    -------
    model : NARX
        Fitted with the chosen structure.
    table : list of dict
        One row per candidate: ``phase`` ("delays" or "neurons"), the structure, ``n_parameters``,
        ``gamma``, ``acf_inside``, ``ccf_inside``, held-out ``nrmse_one_step`` and ``decision``.
    """
    delay_grid, hidden_grid = _ascending(delays, "delays"), _ascending(hidden, "hidden")
    if not 0.0 < holdout <= 0.5:
        raise ParameterError(f"holdout must be in (0, 0.5]. Got {holdout!r}.")
    if not (0.0 < min_inside <= 1.0 and 0.0 < gamma_ratio <= 1.0 and min_improvement >= 0.0):
        raise ParameterError("min_inside and gamma_ratio must be in (0, 1], min_improvement >= 0. "
                             f"Got {min_inside!r}, {gamma_ratio!r}, {min_improvement!r}.")
    u_arr, y_arr = check_signals(u, y)
    split = int(round((1.0 - holdout) * y_arr.shape[0]))
    head, tail = (u_arr[:split], y_arr[:split]), (u_arr[split:], y_arr[split:])

    def trial(d: int, h: int) -> tuple[NARX, dict[str, Any]]:
        model = NARX(input_delays=d, output_delays=d, hidden=h, **narx_params).fit(*head)
        row = _evaluate(model, *tail, max_lag)
        event(_log, "narx structure tried", delays=d, hidden=h, gamma=row["gamma"], nrmse=row["nrmse_one_step"])
        return model, row

    table: list[dict[str, Any]] = []
    best: NARX | None = None
    best_row: dict[str, Any] = {}
    for d in delay_grid:
        model, row = trial(d, hidden_grid[0])
        row["phase"] = "delays"
        table.append(row)
        if best is not None and row["nrmse_one_step"] > (1.0 - min_improvement) * best_row["nrmse_one_step"]:
            row["decision"] = "longer delay lines no longer lower the held-out error: keep the shorter ones"
            break
        best, best_row = model, row
        if min(row["acf_inside"], row["ccf_inside"]) >= min_inside:
            row["decision"] = "correlations inside the bounds: delay lines long enough"
            break
        row["decision"] = "correlations outside the bounds: lengthen the delay lines"
    assert best is not None
    d_best = best.input_delays
    for h in hidden_grid[1:]:
        if best_row["gamma"] < gamma_ratio * best_row["n_parameters"]:
            best_row["decision"] += "; γ well below the parameter count: enough neurons"
            break
        model, row = trial(d_best, h)
        row["phase"] = "neurons"
        table.append(row)
        if row["nrmse_one_step"] > (1.0 - min_improvement) * best_row["nrmse_one_step"]:
            row["decision"] = "little decrease of the held-out error: keep the smaller network"
            break
        row["decision"] = "held-out error decreased"
        best, best_row = model, row
    best_row["chosen"] = True
    if refit:
        best = NARX(input_delays=d_best, output_delays=d_best, hidden=best.hidden, **narx_params).fit(u_arr, y_arr)
    return best, table
