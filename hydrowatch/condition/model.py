"""The condition model: parity features + a state decision + the open-set rule, fitted and stored together.

Analogue of :class:`hydrowatch.health.model.HealthModel` working from raw windows instead of
reference-model prediction errors. The decision is either

- :class:`~hydrowatch.condition.rule.ParityRule` (default): the state whose physics explains the
  window best, the smallest sum over relations of log F[r, k] + w·log F_level[r, k] (a generalised likelihood ratio for
  Gaussian residuals, the level-box term a soft prior on the trained severity that breaks ties
  of look-alike states in holds); probabilities are softmax(−score / T + log π) with T fitted
  on the training windows (temperature scaling, as the health classifier does) but not below the
  relations' model error, and π uniform unless a prior for ``healthy`` is asked for; or
- a :class:`hydrowatch.health.classifier.HealthClassifier` (the study's network, section 6.5) on
  the same features: it fits the training command perfectly but learns the pattern of the
  identification experiment's scores, which the bench shows does not carry to holds and ramps.

Verdicts judge each window alone, or pool the evidence of a machine's last n windows
(``smoothing``, :class:`~hydrowatch.condition.stream.ConditionStream`,
:mod:`hydrowatch.condition.evidence`): look-alike valve faults in holds are then told apart and
an unseen one is rejected, at the price of delay.

``save``/``load`` use one directory: ``condition_features.json``, ``decision.json`` or
``classifier.npz``, ``open_set.json``, ``condition_model.json`` (format 3: ``pooled_excess`` and, since
commissioning, ``pool_open_set``;
directories of format 2, without it, load with the default) (no pickle).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from hydrowatch.condition.evidence import (
    SUPPORT_POINTS,
    EvidenceLayout,
    operating_points,
    pooled_windows,
    trailing_count,
    trailing_evidence,
    trailing_spans,
    trailing_support,
)
from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.condition.pooled_rules import CLEAR_FACTOR as CLEAR_FACTOR  # re-exported: the model's defaults
from hydrowatch.condition.pooled_rules import CLEAR_WINDOWS as CLEAR_WINDOWS
from hydrowatch.condition.pooled_rules import POOLED_EXCESS, Columns
from hydrowatch.condition.rule import ParityRule
from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.classifier import HealthClassifier, labelled_rows
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.health.verdict import judge
from hydrowatch.verdict import Verdict

FILES = {"features": "condition_features.json", "rule": "decision.json", "classifier": "classifier.npz",
         "open_set": "open_set.json", "model": "condition_model.json"}
FORMAT = 3
"""Version of the saved directory: 3 adds ``condition_model.json`` (``pooled_excess``); 2 lacks it and loads
with the default."""

class ConditionModel:
    """Raw windows in, verdicts out: :class:`ConditionFeatures` + decision + :class:`OpenSetRule`.

    Parameters
    ----------
    features : ConditionFeatures, optional
        Unfitted template; default ``ConditionFeatures()``.
    classifier : HealthClassifier, optional
        Unfitted template; None (default) decides with :class:`ParityRule`.
    open_set : OpenSetRule, optional
        Unfitted template; default ``OpenSetRule(quantile=0.995, margin=3.0)``.
    pooled_excess : float, default :data:`POOLED_EXCESS` (2.0)
        Open-set limit for evidence pooled over a machine's windows (``smoothing`` > 1,
        :class:`~hydrowatch.condition.stream.ConditionStream`): unknown when the best known state
        leaves min_k Σ_r (F̄[r, k] − 1) above it, i.e. on average over the pooled windows three times
        the free fit's residual power on one relation (see :data:`POOLED_EXCESS` for what set it).

    Attributes
    ----------
    features_, decision_, open_set_
        The fitted parts.
    pool_open_set_ : bool
        Whether pooled verdicts also pool the open-set evidence (:meth:`pools_open_set`); False for a
        commissioned unit whose supply its recording did not determine.
    """

    def __init__(self, *, features: ConditionFeatures | None = None, classifier: HealthClassifier | None = None,
                 open_set: OpenSetRule | None = None, pooled_excess: float = POOLED_EXCESS) -> None:
        self.features = features
        self.classifier = classifier
        self.open_set = open_set
        self.pooled_excess = pooled_excess

    def fit(self, windows_by_state: Mapping[str, np.ndarray]) -> ConditionModel:
        """Fit all parts on raw windows per state, shape (n_k, window, 4); returns self."""
        if not self.pooled_excess > 0.0:
            raise ParameterError(f"pooled_excess must be > 0. Got {self.pooled_excess!r}; {POOLED_EXCESS} is the "
                                 "default.")
        self.pooled_excess_ = float(self.pooled_excess)
        self.pool_open_set_: bool = True
        template = self.features or ConditionFeatures()
        self.features_ = ConditionFeatures(**template.get_params()).fit(windows_by_state)
        states = list(self.features_.states_)
        X, y = labelled_rows({s: self.features_.transform_with_levels(windows_by_state[s]) for s in states})
        if self.classifier is None:
            rule = ParityRule(level_weight=self.features_.level_weight)
            self.decision_: ParityRule | HealthClassifier = rule.fit(X, y, states)
        else:
            self.decision_ = HealthClassifier(**self.classifier.get_params()).fit(X, y, classes=states)
        template_rule = self.open_set or OpenSetRule(quantile=0.995, margin=3.0)
        self.open_set_ = OpenSetRule(**template_rule.get_params()).fit(X[:, : X.shape[1] // 2], y, states)
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "open_set_"):
            raise NotFittedError("ConditionModel must be fitted before use. Call fit(...) or ConditionModel.load(dir).")

    def predict(self, windows: np.ndarray, smoothing: int = 1) -> np.ndarray:
        """State per raw window, shape (n,): a trained state, ``unknown`` or ``invalid`` (see :meth:`judge`)."""
        return np.asarray([v.state for v in self.judge(windows, smoothing)])

    def judge(self, windows: np.ndarray, smoothing: int = 1) -> list[Verdict]:
        """Verdicts of raw windows, shape (n_windows, window, 4 or 5).

        Parameters
        ----------
        smoothing : int, default 1
            Valid windows whose evidence each verdict pools (:mod:`hydrowatch.condition.evidence`):
            1 judges every window alone; n > 1 takes ``windows`` as consecutive windows of one
            machine and judges each on itself and the n − 1 valid windows before it, the
            windows sharing one severity of each state's fault.
        """
        return self.judge_with_scores(windows, smoothing)[0]

    def judge_with_scores(self, windows: np.ndarray, smoothing: int = 1,
                          rows: np.ndarray | None = None) -> tuple[list[Verdict], np.ndarray]:
        """:meth:`judge` and each window's band-box scores (``features_.transform``, (n, n_features)) in one pass.

        ``rows``: the windows' ``features_.transform_evidence`` when the caller has them already."""
        self._check_fitted()
        rows = self.features_.transform_evidence(windows) if rows is None else rows
        pooled = smoothing > 1
        verdicts = self.judge_rows(rows, smoothing, self.features_.window_reasons(windows),
                                   self.features_.layout_for(windows) if pooled else None,
                                   operating_points(windows) if pooled else None)
        return verdicts, rows[:, : len(self.features_.feature_names_)]

    def judge_rows(self, rows: np.ndarray, smoothing: int = 1, reasons: Sequence[str | None] | None = None,
                   layout: EvidenceLayout | None = None, points: np.ndarray | None = None,
                   support_points: int = SUPPORT_POINTS) -> list[Verdict]:
        """Verdicts of one machine's consecutive windows from their ``features_.transform_evidence`` rows (n, ...).

        The one path from evidence rows to verdicts (:meth:`judge` and the benchmarks that judge the same rows at
        several pool sizes go through it): ``smoothing`` as in :meth:`judge`; ``reasons`` (n,) why a window is
        invalid; ``layout`` the windows' ``features_.layout_for`` and ``points`` their
        :func:`~hydrowatch.condition.evidence.operating_points` (both needed when ``smoothing`` > 1). A pool reads
        ``unknown`` only as :data:`CLEAR_FACTOR` allows, and a fault only where windows at ``support_points``
        operating points support it (:data:`~hydrowatch.condition.evidence.SUPPORT_POINTS`; 1: no such rule).
        """
        self._check_fitted()
        ratios = rows[:, : 2 * len(self.features_.feature_names_)]
        if smoothing == 1:
            return self.judge_evidence(ratios, ratios, reasons)
        if layout is None or points is None:
            raise ParameterError("layout and points are needed to pool windows (smoothing > 1): pass "
                                 "model.features_.layout_for(windows) and evidence.operating_points(windows).")
        unknown = trailing_count(self.alone_unknown(ratios), rows, smoothing)  # the rows trailing_evidence pools
        supported = trailing_support(self.alone_leads(ratios), points, rows, smoothing, support_points)
        return self.judge_pooled(*trailing_evidence(rows, smoothing, layout), ratios, reasons,
                                 windows=pooled_windows(rows, smoothing), support=unknown, supported=supported,
                                 spans=trailing_spans(points, rows, smoothing, support_points))

    def alone_leads(self, ratios: np.ndarray) -> np.ndarray:
        """Whether each window alone prefers each state to ``healthy`` by the decision's margin, shape (n, n_states)
        (``healthy`` itself, NaN rows: False; every fault True when the decision is not a :class:`ParityRule` or
        knows no ``healthy``: then no support is asked, :data:`~hydrowatch.condition.evidence.SUPPORT_POINTS`).

        ``ratios`` (n, 2 · n_features): each window's own band then level ratios."""
        self._check_fitted()
        r = np.atleast_2d(np.asarray(ratios, dtype=np.float64))
        rule, states = self.decision_, np.asarray(self.decision_.classes_)
        healthy = states == "healthy"
        if not isinstance(rule, ParityRule) or not healthy.any():
            return np.tile(~healthy, (r.shape[0], 1))
        logits = rule._logits(r)
        lead = np.zeros(logits.shape, dtype=bool)
        ok = np.all(np.isfinite(logits), axis=1)
        lead[ok] = logits[ok] - logits[ok][:, healthy] > rule.healthy_margin
        lead[:, healthy] = False
        return cast(np.ndarray, lead)

    def alone_unknown(self, ratios: np.ndarray) -> np.ndarray:
        """Whether each window alone is beyond every known state by the open-set rule, shape (n,) (NaN rows: False).

        ``ratios`` (n, 2 · n_features): each window's own band then level ratios. Pooled verdicts count these
        (:data:`CLEAR_FACTOR`)."""
        self._check_fitted()
        r = np.atleast_2d(np.asarray(ratios, dtype=np.float64))
        return cast(np.ndarray, self.open_set_.is_unknown(r[:, : r.shape[1] // 2]))

    def pools_open_set(self) -> bool:
        """Whether pooled windows also pool the open-set evidence: only when the sensors test every relation.

        With a sensor missing, the fills leave known states an occasional unexplained window (a
        step the fill's static relation misses); pooled arithmetically it would spread over the
        next windows, so the open-set rule then judges each window alone and pooling only serves
        the decision. Likewise for a commissioned unit whose supply the recording did not
        determine (``pool_open_set_`` False, :mod:`~hydrowatch.condition.commission`).
        """
        self._check_fitted()
        return getattr(self, "pool_open_set_", True) and set(self.features_.relations_) == {"load", "motor", "valve"}

    def judge_pooled(self, decision: np.ndarray, open_set: np.ndarray, current: np.ndarray,
                     reasons: Sequence[str | None] | None = None, *, windows: np.ndarray,
                     support: np.ndarray, supported: np.ndarray, spans: np.ndarray) -> list[Verdict]:
        """Verdicts from pooled scores (:func:`~hydrowatch.condition.evidence.trailing_evidence`) and each
        window's own ratios ``current``, all shape (n, n_features); ``windows`` (n,): how many windows each row
        pools (:func:`~hydrowatch.condition.evidence.pooled_windows`; the probabilities weigh the evidence by it,
        :meth:`ParityRule.predict_proba`); ``support`` (n,): how many of them read ``unknown`` alone
        (:meth:`alone_unknown`, :func:`~hydrowatch.condition.evidence.trailing_count`). Both are required: a pool
        judged without them is not what :meth:`judge` gives (until 2026-11-27 the unseen-units benchmark left
        ``support`` out and measured pools without :data:`CLEAR_FACTOR`'s rule). ``supported`` (n, n_states): whether
        windows at :data:`~hydrowatch.condition.evidence.SUPPORT_POINTS` operating points of each pool prefer each
        state to ``healthy`` alone (:func:`~hydrowatch.condition.evidence.trailing_support`); a pooled fault without
        it gives way to the window's own verdict. ``spans`` (n,): whether each pool spans those operating points
        (the same count over all its windows); where it does not, the window's own open-set verdict stands
        (:data:`~hydrowatch.condition.evidence.SUPPORT_POINTS`: the windows of one hold share the relations' model
        error there, one piece of evidence, which the window alone has already judged). See :meth:`pools_open_set`."""
        decision, current = np.atleast_2d(decision), np.atleast_2d(current)
        pooled = np.asarray(spans, dtype=bool).reshape(-1) & self.pools_open_set()
        windows = np.asarray(windows).reshape(-1)
        verdicts: list[Verdict] = [cast(Verdict, None)] * decision.shape[0]
        for rows, pool in ((np.flatnonzero(pooled), True), (np.flatnonzero(~pooled), False)):
            if not rows.size:
                continue
            why = [reasons[i] for i in rows.tolist()] if reasons is not None else None
            if pool:
                got = self.judge_evidence(decision[rows], np.atleast_2d(open_set)[rows], why, pooled=True,
                                          windows=windows[rows], support=np.asarray(support).reshape(-1)[rows])
            else:
                got = self.judge_evidence(decision[rows], np.where(np.isfinite(decision[rows]), current[rows], np.nan),
                                          why, windows=windows[rows])
            for i, v in zip(rows.tolist(), got):
                verdicts[i] = v
        index = {c: k for k, c in enumerate(np.asarray(self.decision_.classes_).tolist()) if c != "healthy"}
        ok = np.atleast_2d(np.asarray(supported, dtype=bool))
        alone = [i for i, v in enumerate(verdicts) if v.state in index and not ok[i, index[v.state]]]
        if alone:
            own = self.judge_evidence(current[alone], current[alone], [reasons[i] for i in alone] if reasons else None)
            for i, v in zip(alone, own):
                verdicts[i] = v
        return verdicts

    def judge_evidence(self, decision: np.ndarray, open_set: np.ndarray, reasons: Sequence[str | None] | None = None,
                       pooled: bool = False, windows: np.ndarray | None = None,
                       support: np.ndarray | None = None) -> list[Verdict]:
        """Verdicts from (pooled) parity scores, each shape (n, n_features) of ``transform_with_levels``.

        ``decision`` feeds the state decision, ``open_set`` (its band half) the open-set rule; for
        one window both are its own scores, for pooled windows the geometric and arithmetic means
        (:mod:`hydrowatch.condition.evidence`), with which ``pooled`` adds the ``pooled_excess``
        limit to the open-set rule, ``windows`` (n,) says how many windows each decision row pools and ``support``
        (n,) how many of them read ``unknown`` alone (:data:`CLEAR_FACTOR`). NaN rows or a reason make a verdict
        ``invalid``.
        """
        self._check_fitted()
        d = np.atleast_2d(np.asarray(decision, dtype=np.float64))
        o = np.atleast_2d(np.asarray(open_set, dtype=np.float64))
        if d.shape != o.shape:
            raise DataError(f"decision and open_set scores must have the same shape. Got {d.shape} and {o.shape}.")
        width = d.shape[1]
        return judge(np.concatenate([d, o], axis=1), cast(Any, Columns(self.decision_, 0, width, windows=windows)),
                     cast(Any, Columns(self.open_set_, width, width + width // 2,
                                        self.pooled_excess_ if pooled else None, windows=windows,
                                        support=support)), reasons)

    def score(self, rec_windows: np.ndarray, n_samples: int | None = None,
              smoothing: int = 1) -> tuple[np.ndarray, list[Verdict]]:
        """Window starts (sample index) and verdicts, like :meth:`HealthModel.score`.

        Parameters
        ----------
        rec_windows : ndarray, shape (n_windows, window, 4)
            From :func:`~hydrowatch.condition.layout.windows_from_recording`.
        n_samples : int, optional
            Length of the recording; default ``window + (n_windows − 1)·hop``.
        smoothing : int, default 1
            See :meth:`judge` (a recording is one machine).
        """
        self._check_fitted()
        w = np.asarray(rec_windows)
        n = n_samples if n_samples is not None else self.features_.window + (w.shape[0] - 1) * self.features_.hop
        return self.features_.window_starts(n), self.judge(w, smoothing)

    def save(self, directory: str | Path) -> None:
        """Write the parts into ``directory`` (created if missing)."""
        self._check_fitted()
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.features_.save(d / FILES["features"])
        if isinstance(self.decision_, ParityRule):
            (d / FILES["rule"]).write_text(json.dumps(self.decision_.to_dict(), indent=1))
        else:
            self.decision_.save(d / FILES["classifier"])
        (d / FILES["open_set"]).write_text(json.dumps(self.open_set_.to_dict(), indent=1))
        (d / FILES["model"]).write_text(json.dumps({"format": FORMAT, "pooled_excess": self.pooled_excess_,
                                                    "pool_open_set": bool(getattr(self, "pool_open_set_", True))}))

    @classmethod
    def load(cls, directory: str | Path) -> ConditionModel:
        """Read a directory written by :meth:`save`."""
        d = Path(directory)
        needed = [FILES["features"], FILES["open_set"]]
        missing = [n for n in needed if not (d / n).is_file()]
        if missing or not ((d / FILES["rule"]).is_file() or (d / FILES["classifier"]).is_file()):
            raise DataError(f"a condition model directory must hold {needed} and {FILES['rule']} or "
                            f"{FILES['classifier']}. Missing {missing or 'the decision'}.", str(d))
        model = cls()
        model.features_ = ConditionFeatures.load(d / FILES["features"])
        try:
            if (d / FILES["rule"]).is_file():
                model.decision_ = ParityRule.from_dict(json.loads((d / FILES["rule"]).read_text()))
            else:
                model.decision_ = HealthClassifier.load(d / FILES["classifier"])
            model.open_set_ = OpenSetRule.from_dict(json.loads((d / FILES["open_set"]).read_text()))
            meta = json.loads((d / FILES["model"]).read_text()) if (d / FILES["model"]).is_file() else {}
        except json.JSONDecodeError as exc:
            raise DataError(f"condition model files must be valid JSON. Got: {exc}.", str(d)) from None
        if int(meta.get("format", 2)) > FORMAT:
            raise DataError(f"condition model format must be <= {FORMAT}. Got {meta['format']}: saved by a newer "
                            "hydrowatch; upgrade hydrowatch to load it.", str(d))
        model.pooled_excess = model.pooled_excess_ = float(meta.get("pooled_excess", POOLED_EXCESS))
        model.pool_open_set_ = bool(meta.get("pool_open_set", True))
        return model

