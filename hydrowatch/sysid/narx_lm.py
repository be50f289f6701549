"""The NARX network and its training: Levenberg-Marquardt with Bayesian regularisation.

The network is the study's two-layer function approximator (Fig. 4.7, Eq. 4.6): a log-sigmoid
hidden layer (Eq. 4.2) and a linear output, ``ŷ = W2ᵀ σ(W1 p + b1) + b2``. Its weights live in
one flat parameter vector θ (float tensor) laid out as

    θ = [W1 | b1 (hidden × (R + 1), row-major: neuron j's R input weights, then its bias),
         W2 (hidden,), b2 (1,)]

so that ``n_parameters = hidden · (R + 2) + 1`` (R regressors; 15/15/35 → 1121, Table 4.6).

Training minimises F = β·E_D + α·E_W (Eq. 4.20, E_D the sum of squared prediction errors,
E_W the sum of squared weights and biases) by Levenberg-Marquardt steps on the Gauss-Newton
Hessian H = 2βJᵀJ + 2αI, and re-estimates α and β after every step from the effective number of
parameters γ = n − 2α·tr(H⁻¹) (Eq. 4.21): α = γ/(2E_W), β = (N − γ)/(2E_D) (MacKay; Foresee and
Hagan, "Gauss-Newton approximation to Bayesian learning", 1997; MATLAB ``trainbr``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import torch
from threadpoolctl import threadpool_limits

from hydrowatch.log import event, get_logger

__all__ = ["LMSettings", "TrainingResult", "forward", "initial_weights", "jacobian", "n_parameters",
           "torch_one_thread", "train"]

_log = get_logger(__name__)

GAMMA_REUSE_RATIO = 1e-4
"""γ reuses the step's Cholesky factor of βJᵀJ + (α+μ)I when μ ≤ this · α (relative error ≤ 1e-4)."""
CONVERGED_ITERATIONS = 5
"""Consecutive iterations with relative changes of E_D and γ/n below ``tol`` that count as converged."""


def n_parameters(n_regressors: int, hidden: int) -> int:
    """Weights and biases of the network: hidden · (R + 2) + 1."""
    return hidden * (n_regressors + 2) + 1


def _split(theta: torch.Tensor, n_regressors: int, hidden: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r1 = n_regressors + 1
    w1b = theta[: hidden * r1].view(hidden, r1)
    w2 = theta[hidden * r1 : hidden * r1 + hidden]
    return w1b, w2, theta[-1]


def forward(theta: torch.Tensor, x1: torch.Tensor, hidden: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Network output (Eq. 4.6 with Eq. 4.2 hidden layer, Eq. 4.17 linear output).

    Parameters
    ----------
    theta : tensor, shape (n_parameters,)
    x1 : tensor, shape (N, R + 1)
        Normalised regressors with a trailing column of ones (the bias input).
    hidden : int

    Returns
    -------
    y_hat : tensor, shape (N,)
        Normalised one-step predictions.
    a : tensor, shape (N, hidden)
        Hidden-layer outputs, reused by :func:`jacobian`.
    """
    w1b, w2, b2 = _split(theta, x1.shape[1] - 1, hidden)
    a = torch.sigmoid(x1 @ w1b.T)
    return a @ w2 + b2, a


def jacobian(theta: torch.Tensor, x1: torch.Tensor, a: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """Analytic Jacobian ∂ŷ/∂θ of the network output, shape (N, n_parameters).

    For a log-sigmoid hidden layer (derivative a(1 − a), Eq. 4.16): ∂ŷ/∂W1_jk = W2_j a_j(1 − a_j) p_k,
    ∂ŷ/∂W2_j = a_j, ∂ŷ/∂b2 = 1; ``out`` (same shape) is filled in place when given.
    """
    n, r1 = x1.shape
    hidden = a.shape[1]
    _, w2, _ = _split(theta, r1 - 1, hidden)
    if out is None:
        out = torch.empty(n, n_parameters(r1 - 1, hidden), dtype=x1.dtype)
    d = a * (1.0 - a) * w2
    torch.mul(d[:, :, None], x1[:, None, :], out=out[:, : hidden * r1].view(n, hidden, r1))
    out[:, hidden * r1 : hidden * r1 + hidden] = a
    out[:, -1] = 1.0
    return out


def initial_weights(n_regressors: int, hidden: int, seed: int | None, dtype: torch.dtype) -> torch.Tensor:
    """Nguyen-Widrow initial weights for a log-sigmoid layer on z-scored inputs, shape (n_parameters,).

    Hidden weight rows point in random directions with magnitude 0.7·hidden^(1/R), scaled to the
    log-sigmoid's active range (±4) over inputs of about ±2; biases spread the neurons' active
    regions evenly; output weights are small uniform, the output bias zero.
    """
    rng = np.random.default_rng(seed)
    magnitude = 0.7 * hidden ** (1.0 / n_regressors)
    directions = rng.standard_normal((hidden, n_regressors))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    w1 = 2.0 * magnitude * directions
    spread = np.linspace(-1.0, 1.0, hidden) if hidden > 1 else np.zeros(1)
    b1 = 4.0 * magnitude * spread * np.sign(w1[:, 0])
    w2 = rng.uniform(-0.5, 0.5, hidden) / np.sqrt(hidden)
    theta = np.concatenate([np.column_stack([w1, b1]).ravel(), w2, [0.0]])
    return torch.as_tensor(theta, dtype=dtype)


@dataclass(frozen=True)
class LMSettings:
    """Levenberg-Marquardt settings (μ start and cap, minimum gradient as MATLAB ``trainbr``)."""

    max_iter: int = 200
    mu: float = 0.005
    mu_max: float = 1e10
    min_grad: float = 1e-7
    tol: float = 1e-6
    patience: int = 6


@dataclass
class TrainingResult:
    """Outcome of :func:`train`: final weights, hyperparameters and the per-iteration history."""

    theta: torch.Tensor
    alpha: float
    beta: float
    gamma: float
    iterations: int
    stop_reason: str
    seconds: float
    history: dict[str, list[float]] = field(default_factory=dict)


def _normal_equations(jac: torch.Tensor, e: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """JᵀJ and Jᵀe; JᵀJ through numpy's matmul, which calls BLAS syrk for a transposed self-product.

    (An explicit form from the Jacobian's Kronecker structure halves the flops of JᵀJ but is
    memory-bound and measured no faster on 2 cores; syrk is compute-bound and steadier.)
    """
    j = jac.numpy()
    return torch.from_numpy(j.T @ j), jac.T @ e


def _trace_inverse(chol: torch.Tensor) -> float:
    """tr(A⁻¹) = ‖L⁻¹‖²_F from the lower Cholesky factor L of A (LAPACK trtri, n³/3 flops)."""
    lower = chol.numpy()
    (trtri,) = scipy.linalg.get_lapack_funcs(("trtri",), (lower,))
    inverse, info = trtri(lower, lower=1)
    if info != 0:
        raise FloatingPointError(f"triangular inverse failed (LAPACK info {info})")
    return float(np.sum(np.tril(inverse) ** 2))


@contextmanager
def torch_one_thread() -> Iterator[None]:
    """Run torch's intra-op work on one thread (restored afterwards).

    On small and medium matrices a parallel region costs more in synchronisation than it saves,
    and on a shared machine far more: batched one-step prediction of 1,000 rows ran at 47,000
    samples/s on two threads against 1,950,000 on one (2 cores, load 8).
    """
    before = torch.get_num_threads()
    if before == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextmanager
def _one_thread() -> Iterator[None]:
    """Run on one thread in every BLAS/OpenMP pool (torch's, numpy's and scipy's).

    Training mixes three thread pools; with two threads each, their spinning workers fight for
    the cores. Measured on 2 shared cores: a 65-weight network 0.2 s on one thread against 15 s on
    two; 15/15/35 on 10,000 samples 0.41 against 1.2 CPU-seconds per iteration. The dominant JᵀJ
    (syrk) is compute-bound and runs near peak on one core.
    """
    with torch_one_thread(), threadpool_limits(limits=1):
        yield


def _sse(theta: torch.Tensor, x1: torch.Tensor, t: torch.Tensor, hidden: int) -> float:
    e = t - forward(theta, x1, hidden)[0]
    return float(e @ e)


class _Validation:
    """Early-stopping bookkeeping: best validation SSE, its state, iterations without improvement."""

    def __init__(self, data: tuple[torch.Tensor, torch.Tensor], hidden: int, patience: int) -> None:
        self.data, self.hidden, self.patience = data, hidden, patience
        self.best_sse = np.inf
        self.best_state: tuple[torch.Tensor, float, float, float] | None = None
        self.fails = 0

    def update(self, theta: torch.Tensor, alpha: float, beta: float, gamma: float) -> float:
        sse = _sse(theta, *self.data, self.hidden)
        if sse < self.best_sse:
            self.best_sse, self.best_state, self.fails = sse, (theta.clone(), alpha, beta, gamma), 0
        else:
            self.fails += 1
        return sse

    @property
    def exhausted(self) -> bool:
        return self.fails >= self.patience


def _hyperparameters(gamma: float, sse: float, ssw: float, n_obs: int, beta: float) -> tuple[float, float]:
    """α = γ/(2E_W), β = (N − γ)/(2E_D) (MacKay; Foresee-Hagan); β kept when N <= γ or E_D = 0."""
    alpha = 1.0 if ssw == 0.0 else gamma / (2.0 * ssw)
    if n_obs > gamma and sse > 0.0:
        beta = (n_obs - gamma) / (2.0 * sse)
    return alpha, beta


def train(
    x1: torch.Tensor,
    t: torch.Tensor,
    theta0: torch.Tensor,
    hidden: int,
    settings: LMSettings,
    validation: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> TrainingResult:
    """Levenberg-Marquardt with Bayesian regularisation (Eqs. 4.20, 4.21), series-parallel data.

    Each iteration: JᵀJ and Jᵀe at θ_k (analytic J, :func:`jacobian`); the damped step solves
    (βJᵀJ + (α+μ)I) δ = βJᵀe − αθ by Cholesky; a step is kept when F = βE_D + αE_W decreases,
    and μ adapts to the gain ratio ρ = actual / predicted decrease (Nielsen's rule: μ ×
    max(1/3, 1 − (2ρ − 1)³) after a kept step, ×2, ×4, … after rejected ones). Then
    γ = n − α·tr((βJᵀJ + αI)⁻¹) (= n − 2α tr(H⁻¹), Eq. 4.21), α = γ/(2E_W), β = (N − γ)/(2E_D).
    Starts from γ = n, as MATLAB ``trainbr``.

    Parameters
    ----------
    x1 : tensor, shape (N, R + 1)
        Normalised regressors with a trailing ones column.
    t : tensor, shape (N,)
        Normalised targets.
    theta0 : tensor, shape (n_parameters,)
    hidden : int
    settings : LMSettings
    validation : (x1_val, t_val), optional
        Early stopping: training stops when the validation SSE has not improved for
        ``settings.patience`` iterations, and the best weights are kept.

    Returns
    -------
    TrainingResult
        ``history`` holds per-iteration lists ``sse`` (E_D, normalised units), ``sse_weights`` (E_W),
        ``alpha``, ``beta``, ``gamma``, ``mu`` (and ``validation_sse``). After each update
        F = βE_D + αE_W = N/2 exactly, so F itself says nothing about convergence.
    """
    with _one_thread():
        return _train(x1, t, theta0, hidden, settings, validation)


def _train(
    x1: torch.Tensor,
    t: torch.Tensor,
    theta0: torch.Tensor,
    hidden: int,
    settings: LMSettings,
    validation: tuple[torch.Tensor, torch.Tensor] | None,
) -> TrainingResult:
    start = time.perf_counter()
    n_obs, n_par = x1.shape[0], theta0.numel()
    theta = theta0.clone()
    eye = torch.eye(n_par, dtype=theta.dtype)
    jac = torch.empty(n_obs, n_par, dtype=theta.dtype)
    y_hat, a = forward(theta, x1, hidden)
    e = t - y_hat
    sse, ssw = float(e @ e), float(theta @ theta)
    gamma = float(n_par)
    alpha, beta = _hyperparameters(gamma, sse, ssw, n_obs, 1.0)
    mu, nu = settings.mu, 2.0
    history: dict[str, list[float]] = {k: [] for k in ("sse", "sse_weights", "alpha", "beta", "gamma", "mu")}
    watch = None if validation is None else _Validation(validation, hidden, settings.patience)
    if watch is not None:
        history["validation_sse"] = []
        watch.update(theta, alpha, beta, gamma)
    quiet, stop_reason, iteration = 0, "max_iter", 0
    for iteration in range(1, settings.max_iter + 1):
        gram, jte = _normal_equations(jacobian(theta, x1, a, out=jac), e)
        gradient = beta * jte - alpha * theta  # −½ ∂F/∂θ
        if float(gradient.norm()) < settings.min_grad:
            stop_reason = "min_grad"
            break
        objective = beta * sse + alpha * ssw
        hessian = beta * gram  # ½ H without the α I
        accepted = False
        while mu <= settings.mu_max:
            chol, info = torch.linalg.cholesky_ex(hessian + (alpha + mu) * eye)
            if int(info) == 0:
                step = torch.cholesky_solve(gradient[:, None], chol)[:, 0]
                trial = theta + step
                y_trial, a_trial = forward(trial, x1, hidden)
                e_trial = t - y_trial
                sse_trial, ssw_trial = float(e_trial @ e_trial), float(trial @ trial)
                gain = objective - (beta * sse_trial + alpha * ssw_trial)
                predicted = float(step @ gradient) + mu * float(step @ step)
                if gain > 0.0:
                    rho = gain / predicted if predicted > 0.0 else 1.0
                    accepted = True
                    break
            mu, nu = mu * nu, nu * 2.0
        if not accepted:
            stop_reason = "mu_max"
            break
        if mu > GAMMA_REUSE_RATIO * alpha:
            chol = torch.linalg.cholesky_ex(hessian + alpha * eye)[0]
        gamma_new = min(max(n_par - alpha * _trace_inverse(chol), 0.0), float(n_par))
        steady = abs(gamma_new - gamma) <= settings.tol * n_par and abs(sse - sse_trial) <= settings.tol * sse
        quiet = quiet + 1 if steady else 0
        theta, e, a, sse, ssw = trial, e_trial, a_trial, sse_trial, ssw_trial
        mu, nu = max(mu * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-20), 2.0
        gamma = gamma_new
        alpha, beta = _hyperparameters(gamma, sse, ssw, n_obs, beta)
        for key, value in (("sse", sse), ("sse_weights", ssw), ("alpha", alpha), ("beta", beta), ("gamma", gamma),
                           ("mu", mu)):
            history[key].append(value)
        event(_log, "lm iteration", level=logging.DEBUG, iteration=iteration, sse=sse, gamma=gamma, mu=mu)
        if watch is not None:
            history["validation_sse"].append(watch.update(theta, alpha, beta, gamma))
            if watch.exhausted:
                stop_reason = "validation"
                break
        if quiet >= CONVERGED_ITERATIONS:
            stop_reason = "converged"
            break
    if watch is not None and stop_reason == "validation" and watch.best_state is not None:
        theta, alpha, beta, gamma = watch.best_state
    return TrainingResult(theta=theta, alpha=alpha, beta=beta, gamma=gamma, iterations=iteration,
                          stop_reason=stop_reason, seconds=time.perf_counter() - start, history=history)
