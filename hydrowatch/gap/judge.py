"""The judgement of one candidate model against the current one, on the held-out blocks (issue 12; used by
diagnose.py for its acceptance rules and its backward step): the relative drop of the held-out cost and its
block-bootstrap standard error, the consistency of the per-block drop, ΔBIC on the fitting blocks (n_eff-corrected),
the share of the error above the noise ceiling removed, the worst sensor's rise and the sensor that improves most;
and :func:`pays`, the gain rule that reads them.
"""

from __future__ import annotations

import math

import numpy as np

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import OutputErrorFit, _effective_fraction
from hydrowatch.gap.candidates import Refit, holdout_cost
from hydrowatch.gap.locate import noise_std

BLOCK_SAMPLES = 200
"""Block length of the held-out bootstrap, samples (1 s)."""


def _normalised_sq_error(aligned: AlignedRecording, prediction: np.ndarray, mask: np.ndarray) -> np.ndarray:
    e = (aligned.measured[:, mask] - prediction[:, mask]) / aligned.scale[:, None]
    return np.sum(e**2, axis=0)


def judge(aligned: AlignedRecording, current: OutputErrorFit, candidate: Refit) -> dict[str, float]:
    """How much ``candidate`` improves on ``current``.

    Returns
    -------
    dict
        ``gain`` (relative drop of the held-out cost), ``gain_se`` (its block-bootstrap standard
        error), ``consistency`` (−mean ln(J₁/J₀) over 1 s held-out blocks / its standard error),
        ``delta_bic`` (fitting blocks, n_eff-corrected), ``explained`` (share of the held-out cost
        above the noise ceiling that the candidate removes), ``worst_sensor`` (largest
        relative rise of one sensor's held-out mean square error; a real effect does not make a
        sensor worse) and ``improved`` (index in SENSORS of the sensor whose held-out error falls most).
    """
    mask = aligned.holdout_mask
    e0 = _normalised_sq_error(aligned, current.prediction, mask)
    e1 = _normalised_sq_error(aligned, candidate.fit.prediction, mask)
    d = e0 - e1
    j0 = holdout_cost(aligned, current.prediction)
    n_blocks = max(d.size // BLOCK_SAMPLES, 2)
    blocks = np.array([b.mean() for b in np.array_split(d, n_blocks)])
    se = float(blocks.std(ddof=1) / math.sqrt(n_blocks)) / j0
    log_ratio = np.array([math.log(max(b1.sum(), 1e-300) / max(b0.sum(), 1e-300))
                          for b0, b1 in zip(np.array_split(e0, n_blocks), np.array_split(e1, n_blocks))])
    consistency = float(-log_ratio.mean() / max(log_ratio.std(ddof=1) / math.sqrt(n_blocks), 1e-12))
    fm = aligned.fit_mask
    r = ((aligned.measured[:, fm] - current.prediction[:, fm]) / aligned.scale[:, None]).ravel()
    n_eff = r.size * _effective_fraction(r, aligned.measured.shape[0])
    dk = len(candidate.fit.z) - len(current.z)
    delta_bic = n_eff * math.log(candidate.fit.fit_cost / current.fit_cost) + dk * math.log(n_eff)
    used = aligned.used_mask
    noise = sum(
        min(noise_std(aligned.measured[i, used] - p[i, used]) for p in (current.prediction, candidate.fit.prediction))
        ** 2 / aligned.scale[i] ** 2 for i in range(aligned.measured.shape[0]))
    per0 = np.mean(((aligned.measured[:, mask] - current.prediction[:, mask]) / aligned.scale[:, None]) ** 2, axis=1)
    per1 = np.mean(((aligned.measured[:, mask] - candidate.fit.prediction[:, mask]) / aligned.scale[:, None]) ** 2,
                   axis=1)
    return {"gain": float(d.mean()) / j0, "gain_se": se, "consistency": consistency, "delta_bic": float(delta_bic),
            "explained": float(d.mean() / max(j0 - noise, 1e-12)), "worst_sensor": float(np.max(per1 / per0 - 1.0)),
            "improved": float(np.argmax(per0 - per1))}


def pays(j: dict[str, float], min_gain: float, majority: float) -> bool:
    """The gain rule of acceptance (:mod:`~hydrowatch.gap.diagnose`): the held-out cost falls by ``min_gain``
    (relative), or by anything while ``majority`` of the held-out error above the noise ceiling goes (``j``:
    :func:`judge`). Only asked while the model fails the discovery test (``diagnose`` runs, and goes on, only then),
    i.e. where what is left is beyond what noise and parameter uncertainty explain. Why: once one effect is in, the
    cost can sit within a few per cent of the ceiling, and no effect lowers the *total* by ``min_gain`` however much
    of what is left it explains (issue 12, seed 2063 unit 9: a pump ripple beside valve saturation removed 52 % of
    it at a total gain of 2.26 %).

    A share above 1 is not a majority but a ceiling that was not measured: the ceiling is read from the residual's
    fast content, and a misfit with fast content of its own (the stops of an unmodelled friction, a backlash's
    impacts) lifts it to the cost itself, so that ``explained`` reads 10⁶–10⁹ for candidates that gain 0.1–3 %
    (seed 2063 units 11 and 13); the relative drop alone decides there."""
    return bool(j["gain"] >= min_gain or (j["gain"] > 0 and majority <= j["explained"] <= 1.0))
