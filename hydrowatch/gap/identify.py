"""What a recording determines about a unit: the calibrated parameters' Fisher information.

After calibration (calibrate.py) the output sensitivities of every calibrated plant parameter are
taken by CENTRAL differences at the estimate (one batched simulation of 2·P models; a forward
difference's truncation error, ~0.5 % of a column, shows as spurious information along exact
symmetries such as βe, Vs, Vt scaled together). The information of the recording is JᵀWJ, J the
sensitivities of the normalised simulation errors on the fitting blocks and W each sensor's inverse
noise variance (its residual's 70–100 Hz band, locate.noise_std): what the sensor noise lets the
record determine, also while the model still misses physics (a residual-variance weighting would
then call nearly everything undetermined). The design-value prior (space.PRIOR_SD) adds
1/PRIOR_SD² per parameter.
A parameter is **determined** when its posterior standard deviation of ln(value) is below
:data:`DETERMINED_SD`; the others are reported as "not determined by this recording", with the
parameters they are entangled with (posterior correlation ≥ :data:`ENTANGLED`) and the experiment
that would determine them. The discovery test (discovery.py) counts the determined ones as the
estimated coordinates; a candidate effect's calibration (hypothesis.py) still refits all of them
(the prior holds the others).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hydrowatch.gap.align import AlignedRecording, simulate_sensors
from hydrowatch.gap.calibrate import OutputErrorFit, intervals
from hydrowatch.gap.locate import noise_std
from hydrowatch.gap.space import PRIOR_SD

DETERMINED_SD = 0.05
"""Posterior standard deviation of ln(value) below which the recording determines a parameter
(a 95 % interval within about ±10 %)."""

ENTANGLED = 0.5
"""|Posterior correlation| at which two parameters are reported as entangled."""

RANK_TOLERANCE = 1e-3
"""Singular values of the weighted sensitivities below this share of the largest count as zero
information (the central differences' error along an exact symmetry is of that order)."""

_STEP = 1e-2
"""Central-difference step on ln(value)."""

_SHARED_EXPERIMENTS: dict[tuple[str, ...], str] = {
    ("Cp", "Cvl"): "a flow meter on the pump outlet or case drain: the sensors see pump and valve leakage only as "
                   "their sum (both leak supply → tank at the supply pressure)",
    ("beta_e",): "a supply- or load-pressure channel, or a known chamber volume: the sensors see the bulk "
                 "modulus only through βe/Vs and βe/Vt",
    ("Vs",): "a supply-pressure channel, or a known bulk modulus: the sensors see the supply volume only through βe/Vs",
    ("Vt",): "a load-pressure channel, or a known bulk modulus: the sensors see the chamber volume only through βe/Vt",
    ("Dp",): "a run that holds the command above the pump limit (|u| ≳ 3.5 V) for several seconds, or a "
             "supply-pressure channel",
    ("Kr", "Pc"): "a supply-pressure channel, or a run that holds the command near zero (relief fully open)",
    ("Bm", "BL"): "steady runs at several constant speeds: motor and load damping then split by the torque sensor",
    ("Jm", "JL"): "fast command steps: motor and load inertia then split by the torque sensor",
    ("omega_v", "zeta_v"): "a swept sine up to 100 Hz, or a spool-position channel",
}
EXPERIMENTS: dict[str, str] = {name: text for names, text in _SHARED_EXPERIMENTS.items() for name in names}
"""The experiment that would determine each parameter a filtered-noise recording may leave open."""

DEFAULT_EXPERIMENT = "a longer recording over more of the operating range (commands −4…4 V, above the pump limit)"


@dataclass(frozen=True)
class Identifiability:
    """Which calibrated parameters a recording determines.

    Attributes
    ----------
    determined : tuple of str
        Plant parameters whose posterior sd of ln(value) is below DETERMINED_SD.
    sd : dict of str to float
        Posterior standard deviation of ln(value) of every calibrated parameter.
    undetermined : dict of str to dict
        ``{name: {"sd": float, "with": [names], "experiment": str}}`` for the others.
    singular_values : list of float
        Singular values of the noise-normalised sensitivity matrix (the data's information alone),
        largest first; a value below 1/DETERMINED_SD is a direction the record leaves to the prior.
    """

    determined: tuple[str, ...]
    sd: dict[str, float]
    undetermined: dict[str, dict[str, object]]
    singular_values: list[float]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form (the report's ``identifiability``)."""
        return {"determined": list(self.determined), "sd_log": {k: round(v, 5) for k, v in self.sd.items()},
                "not_determined": self.undetermined, "threshold_sd_log": DETERMINED_SD,
                "singular_values": [round(v, 3) for v in self.singular_values]}


def identify(aligned: AlignedRecording, fit: OutputErrorFit) -> tuple[Identifiability, OutputErrorFit]:
    """The identifiability of ``fit``'s plant parameters, and ``fit`` with its covariance and 95 %
    intervals recomputed from the central-difference information.

    Parameters
    ----------
    aligned : AlignedRecording
    fit : OutputErrorFit
        A calibration (plant coordinates only, with or without the design-value prior).
    """
    space = fit.space
    names = space.plant_free
    k = len(names)
    points = [fit.z]
    for i in range(k):
        for h in (_STEP, -_STEP):
            z = fit.z.copy()
            z[i] += h
            points.append(z)
    models = [space.model(z) for z in points]
    preds = simulate_sensors(aligned, [m[0] for m in models], [m[1] for m in models])
    m = aligned.fit_mask

    def residual(p: np.ndarray) -> np.ndarray:
        return ((aligned.measured[:, m] - p[:, m]) / aligned.scale[:, None]).ravel()

    # Rows weighted by each sensor's noise variance (normalised units), read from the residual's 70–100 Hz
    # band: the information the recording holds about the parameters, whether or not the model is right yet.
    used = aligned.used_mask
    ceiling = np.array([noise_std(aligned.measured[i, used] - preds[0][i, used]) / aligned.scale[i]
                        for i in range(aligned.measured.shape[0])])
    weight = np.repeat(1.0 / ceiling, int(m.sum()))
    jac = np.column_stack([(residual(preds[1 + 2 * i]) - residual(preds[2 + 2 * i])) / (2 * _STEP) for i in range(k)])
    jac *= weight[:, None]
    _, singular, vt = np.linalg.svd(jac, full_matrices=False)
    kept = singular > RANK_TOLERANCE * singular[0]  # numerical rank: the rest is finite-difference error
    information = (vt[kept].T * singular[kept] ** 2) @ vt[kept]
    if space.prior is not None:
        information[np.arange(k), np.arange(k)] += 1.0 / PRIOR_SD**2
    cov = np.linalg.pinv(information)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(np.maximum(sd, 1e-300), np.maximum(sd, 1e-300))
    determined = tuple(n for n, s in zip(names, sd) if s < DETERMINED_SD)
    undetermined: dict[str, dict[str, object]] = {}
    for i, n in enumerate(names):
        if sd[i] < DETERMINED_SD:
            continue
        partners = [names[j] for j in np.argsort(-np.abs(corr[i])) if j != i and abs(corr[i, j]) >= ENTANGLED]
        undetermined[n] = {"sd": round(float(sd[i]), 4), "with": partners,
                           "experiment": EXPERIMENTS.get(n, DEFAULT_EXPERIMENT)}
    full = np.zeros_like(fit.covariance)
    full[:k, :k] = cov
    if fit.covariance.shape[0] > k:
        full[k:, k:] = fit.covariance[k:, k:]
    refined = replace(fit, covariance=full, ci95=intervals(space, fit.z, full))
    result = Identifiability(determined, {n: float(s) for n, s in zip(names, sd)}, undetermined,
                             [float(v) for v in singular])
    return result, refined
