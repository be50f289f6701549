"""Evidence rows of :class:`~hydrowatch.condition.features.ConditionFeatures`: the ratios, plus what pooling needs.

A window's evidence row holds the band- and level-box ratios of every state and relation, then each state's free
estimate of its own fault's severity and that estimate's weight (curvature over its relation's free MSE), so that a
pool of windows can share one severity per state (:mod:`hydrowatch.condition.evidence`). Split from
``features.py`` (one module, one job): these methods are mixed into ``ConditionFeatures``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from hydrowatch.condition import estimates as E
from hydrowatch.condition import layout as L
from hydrowatch.condition import ratios as R
from hydrowatch.condition.evidence import STATE_COLUMNS, EvidenceLayout
from hydrowatch.condition.features_boxes import RELIEF_LIMITS, StateBoxes
from hydrowatch.condition.oil import temperature_known
from hydrowatch.condition.relief import window_factors
from hydrowatch.condition.standstill import stalled
from hydrowatch.plant.faults import FAULTS, parse_state
from hydrowatch.plant.parameters import PlantParameters

RELATION_OF: dict[str, str] = {"load": "load", "motor_leak": "motor", **{f: "valve" for f in E.parity.VALVE_HYPOTHESES}}
"""The relation in which each fault's parameter appears."""


class EvidenceRows(StateBoxes):
    """The evidence methods of :class:`~hydrowatch.condition.features.ConditionFeatures` (a mixin)."""

    states_: tuple[str, ...]
    relations_: tuple[str, ...]
    feature_names_: list[str]
    window: int
    nominal_: PlantParameters
    if TYPE_CHECKING:  # ConditionFeatures provides these
        def _check_fitted(self) -> None: ...
        def _by_oil(self, windows: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, bool]]: ...
        def _estimates(self, w: np.ndarray) -> tuple[np.ndarray, list[R.FillGroup]]: ...
        def _ratios(self, groups: list[R.FillGroup], known: bool, sets: int = 2
                    ) -> tuple[list[np.ndarray], dict[str, np.ndarray], list[np.ndarray]]: ...

    def transform_evidence(self, windows: np.ndarray) -> np.ndarray:
        """:meth:`transform_with_levels` plus what pooling windows with one severity needs, NaN rows invalid.

        Shape (n_windows, :meth:`evidence_width`): the band and level ratios, then for every
        state the free estimate of its own fault's severity (n_states), then that fault's curvature
        d(MSE)/d(s²) over its relation's free MSE, 1/severity² (n_states; 0 for healthy), then the ratio of the
        state's own valve relation explained by the other valve-side faults in its band box and in its level box
        (2 · n_states; :data:`~hydrowatch.condition.ratios.NO_OTHER_EXPLANATION` where its own fault is not
        valve-side: nothing else explains that relation). See
        :mod:`hydrowatch.condition.evidence` and :meth:`evidence_layout` (of the windows' oil part).
        """
        return self.evidence_and_estimates(windows)[0]

    def evidence_width(self) -> int:
        """Values in a :meth:`transform_evidence` row: 2 · n_features + :data:`STATE_COLUMNS` · n_states."""
        return 2 * len(self.feature_names_) + STATE_COLUMNS * len(self.states_)

    def evidence_and_estimates(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray, E.ParityEstimates | None]:
        """:meth:`transform_evidence` rows, the valid-window mask (n,) and the valid windows' estimates at the
        nominal fill (None when no window is valid), from one fit of the relations: what the degradation index
        reads (:func:`hydrowatch.condition.degradation.features_degradation`) beside the verdicts."""
        parts = self._by_oil(windows)
        n = sum(int(m.sum()) for m, _, _ in parts)
        out = np.full((n, self.evidence_width()), np.nan)
        valid = np.zeros(n, dtype=bool)
        found: list[tuple[np.ndarray, E.ParityEstimates]] = []
        for mask, w, known in parts:
            rows, ok, estimates = self._evidence(w, known)
            out[mask], valid[mask] = rows, ok
            if estimates is not None:
                at = np.zeros(n, dtype=bool)
                at[np.flatnonzero(mask)[ok]] = True
                found.append((at, estimates))
        return out, valid, E.merged_estimates(found, valid)

    def _evidence(self, w: np.ndarray, known: bool) -> tuple[np.ndarray, np.ndarray, E.ParityEstimates | None]:
        """:meth:`evidence_and_estimates` of one oil part (``known``: the windows carry the oil temperature)."""
        ok, groups = self._estimates(w)
        k = len(self.states_)
        out = np.full((ok.size, self.evidence_width()), np.nan)
        if not groups:
            return out, ok, None
        (band, level), free, (band_others, level_others) = self._ratios(groups, known)
        severity, weight = np.zeros((band.shape[0], k)), np.zeros((band.shape[0], k))
        faults = self._own_faults()
        for g in groups:
            for j in g.states:
                fault = faults[j]
                if fault is not None:
                    weight[:, j] = g.estimates.curvature[fault] / np.maximum(free[RELATION_OF[fault]], 1e-300)
                    severity[:, j] = g.estimates.severity[fault]
                    if self._follows_relief(self.states_[j]):  # in the commissioned relief's frame (module relief)
                        frame = window_factors(self._load_scale(), g.estimates.severity["relief_spring"],
                                               g.estimates.curvature["relief_spring"], RELIEF_LIMITS)[2]
                        severity[:, j] /= np.where(frame > 0.0, frame, 1.0)
                        weight[:, j] *= frame**2
        load = np.array([f == "load" for f in faults], dtype=bool)
        weight[np.ix_(self._stalled(groups), load)] = 0.0  # no load severity where the load relation is not judged
        out[ok] = np.concatenate([band, level, severity, weight, band_others, level_others], axis=1)
        return out, ok, groups[0].estimates  # the nominal fill comes first (:meth:`_estimates`)

    def _stalled(self, groups: Sequence[R.FillGroup]) -> np.ndarray:
        """Valid windows whose load relation is not judged (:mod:`hydrowatch.condition.standstill`), shape (m,)."""
        return stalled(groups, self.nominal_.omega_s, getattr(self, "brake_open_", False))

    def _own_faults(self) -> list[str | None]:
        """Each state's own fault, None for healthy or where the sensors cannot test its relation."""
        faults = [parse_state(state)[0] for state in self.states_]
        return [f if f is not None and RELATION_OF[f] in self.relations_ else None for f in faults]

    def evidence_layout(self, temperature: bool = True) -> EvidenceLayout:
        """Where :meth:`transform_evidence` puts each state's own fault, and its band and level boxes (those of
        windows without the oil temperature when ``temperature`` is False, :meth:`_box_sets`)."""
        self._check_fitted()
        band, level = self._box_sets(temperature)
        k = len(self.states_)
        columns = np.full(k, -1, dtype=np.int64)
        bounds = np.zeros((2, k, 2))
        for j, (state, fault) in enumerate(zip(self.states_, self._own_faults())):
            if fault is not None:
                columns[j] = self.relations_.index(RELATION_OF[fault]) * k + j
                bounds[0, j], bounds[1, j] = band[state][fault], level[state][fault]
        return EvidenceLayout(columns, bounds, prior_once=set(self.relations_) == set(E.RELATIONS))

    def layout_for(self, windows: np.ndarray) -> EvidenceLayout:
        """:meth:`evidence_layout` for one machine's raw ``windows``: with the oil temperature only if all carry it."""
        w = L.check_windows(windows, self.window)
        return self.evidence_layout(bool(temperature_known(w, L.WIDTH).all()))

    def severities(self, windows: np.ndarray) -> dict[str, np.ndarray]:
        """Unconstrained severity estimates of every fault per window, ``{fault: (n_windows,)}`` (NaN where invalid)."""
        _, valid, estimates = self.evidence_and_estimates(windows)
        out = {f: np.full(valid.size, np.nan) for f in FAULTS}
        if estimates is not None:
            for f in FAULTS:
                out[f][valid] = estimates.severity[f]
        return out

