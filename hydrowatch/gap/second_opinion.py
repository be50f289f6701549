"""A second opinion on named effects: stability-selected sparse regression over the regressor library.

gap-method.md, step 4: "Sparse regression over the regressor library (SINDy with control, ensemble /
stability selection) is a good second opinion". For each sensor whose residual is coloured, the
residual of a model ``e = y − ŷ`` is regressed on the library Θ(u, ŷ, t) of correction.py by
sequentially thresholded least squares (Brunton, Proctor & Kutz 2016), refitted on ``n_fits``
block-bootstrap resamples of the record (1 s blocks, drawn with replacement; ensemble SINDy after
Fasel et al. 2022, stability selection after Meinshausen & Bühlmann 2010). A term is *stable* when
it is selected in at least ``frequency`` of the fits. Each stable term points at the catalog
effects whose signature it is (TERM_EFFECTS, plant-model.md): the second opinion *agrees* with a
named effect when one of its stable terms points at it.

The terms that merely re-weight the nominal structure (1, u, ω, T, Q) point at no effect: a
calibrated parameter change shows as them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.errors import NotFittedError, ParameterError
from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.correction import Library, SparseCorrection, build_library, stlsq
from hydrowatch.gap.diagnose import WHITE_LIMIT
from hydrowatch.gap.locate import whiteness
from hydrowatch.recording import SENSORS

RATE_TERMS = ("du/dt", "dω/dt", "dT/dt", "dQ/dt")
"""Rate terms: a lag or a dead time anywhere in the loop shows as −τ·dŷ/dt, so they are shared."""

TERM_EFFECTS: dict[str, tuple[str, ...]] = {
    "u(t−20 ms)": ("transport_delay",),
    "du/dt": ("transport_delay", "valve_hysteresis"),
    "sign(du/dt)": ("valve_hysteresis", "gear_backlash"),
    "max(0.5 V − u, 0)": ("valve_deadband",),
    "max(u − 3 V, 0)": ("valve_saturation",),
    "ω·|ω|": ("quadratic_drag",),
    "exp(−(ω/ω0)²)": ("stribeck_friction",),
    "dω/dt": ("shaft_compliance", "gear_backlash", "sensor_lowpass", "transport_delay"),
    "dT/dt": ("shaft_compliance", "entrained_air", "sensor_lowpass", "transport_delay"),
    "dQ/dt": ("entrained_air", "sensor_lowpass", "transport_delay"),
    "t": ("thermal_drift",),
    "t·T": ("thermal_drift",),
    "sin(ωp·t)": ("pump_ripple",),
    "cos(ωp·t)": ("pump_ripple",),
    "sin(2ωp·t)": ("pump_ripple",),
    "cos(2ωp·t)": ("pump_ripple",),
}
"""Library term → the catalog effects whose signature it is (plant-model.md, "where it shows").

A dead time or a lag τ shifts the response: ŷ(t − τ) ≈ ŷ − τ·dŷ/dt, so the rate terms point at
every dynamic effect; the level and shape terms are specific (ω|ω| only at drag, exp(−(ω/ω0)²)
only at breakaway friction, the ripple lines only at the pump)."""


def unique_shares(library: Library, residual: np.ndarray, rows: np.ndarray, names: list[str]) -> dict[str, float]:
    """Share of the residual's mean square each term explains that the others cannot (a partial R²).

    Least squares of ``residual[rows]`` on the named terms (plus the constant), then each term left
    out in turn: ``(SSE without the term − SSE with all) / Σ residual²``.

    Returns
    -------
    dict of str to float
        ``{term: share}``, 0…1, for every named term except the constant.
    """
    cols = ["1", *[n for n in names if n != "1"]]
    theta = np.column_stack([library.column(n) for n in cols])[rows]
    y = residual[rows]
    total = float(y @ y) or 1.0

    def sse(keep: list[int]) -> float:
        coef, *_ = np.linalg.lstsq(theta[:, keep], y, rcond=None)
        r = y - theta[:, keep] @ coef
        return float(r @ r)

    full = sse(list(range(len(cols))))
    return {n: max(sse([j for j in range(len(cols)) if j != i]) - full, 0.0) / total
            for i, n in enumerate(cols) if i > 0}


class StabilitySelection:
    """Ensemble STLSQ: which library terms a residual needs, and how reliably.

    Parameters
    ----------
    n_fits : int, default 100
        Block-bootstrap resamples.
    block_samples : int, default 200
        Bootstrap block length, samples (1 s at 200 Hz).
    frequency : float, default 0.8
        Selection frequency from which a term counts as stable.
    thresholds : tuple of float, default (0.05, 0.1, 0.2)
        STLSQ thresholds; the one with the lowest held-out error on the whole record is used in
        every resample (a threshold below 0.05 of the residual's std selects noise terms).
    seed : int, default 0
        Seed of the resampling.

    Attributes
    ----------
    names_ : tuple of str
    threshold_ : float
    frequency_ : ndarray, shape (K,)
        Share of the fits that selected each term.
    coef_ : ndarray, shape (K,)
        Median coefficient over the fits that selected the term (0 where never), library units.
    stable_ : dict of str to float
        Terms selected in at least ``frequency`` of the fits, with their median coefficients.
    importance_ : dict of str to float
        Per stable term, the share of the residual's mean square it alone explains
        (:func:`unique_shares`).
    """

    def __init__(self, *, n_fits: int = 100, block_samples: int = 200, frequency: float = 0.8,
                 thresholds: tuple[float, ...] = (0.05, 0.1, 0.2), seed: int = 0) -> None:
        self.n_fits = n_fits
        self.block_samples = block_samples
        self.frequency = frequency
        self.thresholds = thresholds
        self.seed = seed

    def fit(self, library: Library, residual: np.ndarray, fit_mask: np.ndarray, holdout_mask: np.ndarray
            ) -> StabilitySelection:
        """Choose the threshold on ``holdout_mask``, then refit on resampled blocks of both masks; returns self."""
        if self.n_fits < 2 or not 0.0 < self.frequency <= 1.0 or self.block_samples < 1:
            raise ParameterError(f"n_fits must be >= 2, frequency in (0, 1] and block_samples >= 1. Got {self.n_fits}, "
                                 f"{self.frequency}, {self.block_samples}. Use e.g. 100, 0.8, 200.")
        chooser = SparseCorrection(thresholds=self.thresholds).fit(library, residual, fit_mask, holdout_mask)
        self.threshold_ = float(chooser.threshold_)
        used = np.flatnonzero(fit_mask | holdout_mask)
        blocks = [used[i:i + self.block_samples] for i in range(0, used.size, self.block_samples)]
        rng = np.random.default_rng(self.seed)
        coefs = np.empty((self.n_fits, library.theta.shape[1]))
        for k in range(self.n_fits):
            rows = np.concatenate([blocks[i] for i in rng.integers(0, len(blocks), len(blocks))])
            coefs[k] = stlsq(library.theta[rows], residual[rows], self.threshold_)
        selected = coefs != 0.0
        self.names_ = library.names
        self.frequency_ = selected.mean(axis=0)
        masked = np.where(selected, coefs, np.nan)
        self.coef_ = np.zeros(coefs.shape[1])
        ever = selected.any(axis=0)
        self.coef_[ever] = np.nanmedian(masked[:, ever], axis=0)
        self.stable_ = {n: float(c) for n, c, f in zip(self.names_, self.coef_, self.frequency_) if f >= self.frequency}
        self.importance_ = unique_shares(library, residual, used, list(self.stable_))
        return self

    @property
    def implicated(self) -> set[str]:
        """Catalog effects the stable terms point at."""
        if not hasattr(self, "stable_"):
            raise NotFittedError("StabilitySelection must be fitted first. Call fit(library, residual, ...).")
        return {e for name in self.stable_ for e in TERM_EFFECTS.get(name, ())}


@dataclass(frozen=True)
class SecondOpinion:
    """Stability selection on every coloured sensor residual of one model.

    Attributes
    ----------
    selections : dict of str to StabilitySelection
        Per sensor whose held-out residual is not white (others need no term).
    residual : str
        Which model's residual it was (``"calibrated"``, or the model before a later effect).
    """

    selections: dict[str, StabilitySelection]
    residual: str

    @property
    def implicated(self) -> list[str]:
        """Catalog effects any stable term points at, the strongest first (:meth:`strength`), then by name."""
        found = {e for s in self.selections.values() for e in s.implicated}
        return sorted(found, key=lambda e: (-self.strength(e), e))

    def strength(self, effect_id: str) -> float:
        """Largest unique share (``importance_``) of a stable term pointing at the effect, 0…1."""
        return max((s.importance_.get(n, 0.0) for s in self.selections.values() for n in s.stable_
                    if effect_id in TERM_EFFECTS.get(n, ())), default=0.0)

    def terms(self) -> dict[str, dict[str, float]]:
        """Stable terms per sensor with their median coefficients (sensor unit per term unit)."""
        return {sensor: {n: round(c, 6) for n, c in s.stable_.items()} for sensor, s in self.selections.items()}

    def frequencies(self) -> dict[str, dict[str, float]]:
        """Selection frequency of every term selected at least once, per sensor."""
        return {sensor: {n: round(float(f), 3) for n, f in zip(s.names_, s.frequency_) if f > 0}
                for sensor, s in self.selections.items()}

    def verdict(self, effect_id: str) -> dict[str, Any]:
        """The report's ``second_opinion`` of one named effect.

        Returns
        -------
        dict
            ``agrees`` (a stable term points at the effect), ``terms`` (the stable terms per sensor
            with their median coefficients), ``supporting`` (``"sensor: term"`` of the stable terms
            pointing at the effect), ``selection_frequency`` (per sensor, every term selected at least
            once), ``specific`` (a supporting term points at this effect alone), ``share`` (the
            largest share of the residual's mean square a supporting term alone explains),
            ``rank`` (1 = the strongest of the implicated effects; None when it does not agree),
            ``implicated`` (all effects the stable terms point at, strongest first) and ``residual``.
        """
        found = [(TERM_EFFECTS[n] != (effect_id,), -float(s.frequency_[s.names_.index(n)]), f"{sensor}: {n}")
                 for sensor, s in self.selections.items() for n in s.stable_ if effect_id in TERM_EFFECTS.get(n, ())]
        supporting = [item for *_, item in sorted(found)]  # terms specific to the effect first, then by frequency
        specific = any(not shared for shared, *_ in found)
        implicated = self.implicated
        return {"agrees": bool(supporting), "specific": specific, "supporting": supporting,
                "share": round(self.strength(effect_id), 4),
                "rank": implicated.index(effect_id) + 1 if effect_id in implicated else None,
                "terms": self.terms(), "selection_frequency": self.frequencies(), "implicated": implicated,
                "residual": self.residual}

    def as_dict(self) -> dict[str, Any]:
        """The report-level ``second_opinion`` (on the calibrated residual): terms, frequencies, implicated."""
        return {"residual": self.residual, "terms": self.terms(), "selection_frequency": self.frequencies(),
                "implicated": self.implicated}


def second_opinion(aligned: AlignedRecording, prediction: np.ndarray, *, pump_speed: float,
                   residual: str = "calibrated", **params: Any) -> SecondOpinion:
    """Stability selection over the library on one model's residual and operating point.

    Parameters
    ----------
    aligned : AlignedRecording
    prediction : ndarray, shape (3, n)
        Noise-free simulation of the model (flow [L/min], speed [rad/s], torque [N·m]): its residual
        is explained, and it is the operating point the library is built from.
    pump_speed : float
        Pump shaft speed ωp, rad/s.
    residual : str, default "calibrated"
        Label of the model, for the report.
    **params
        Parameters of :class:`StabilitySelection`.
    """
    library = build_library(aligned.voltage, prediction, aligned.t, pump_speed=pump_speed)
    error = aligned.measured - prediction
    selections = {}
    for i, sensor in enumerate(SENSORS):
        if whiteness(error[i, aligned.holdout_mask]) < WHITE_LIMIT:
            continue
        selections[sensor] = StabilitySelection(**params).fit(library, error[i], aligned.fit_mask,
                                                              aligned.holdout_mask)
    return SecondOpinion(selections, residual)


__all__ = ["TERM_EFFECTS", "SecondOpinion", "StabilitySelection", "second_opinion"]
