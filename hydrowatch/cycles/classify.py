"""A per-component classifier of cycles: per-cycle features → linear discriminant analysis.

Two feature sets (module :mod:`hydrowatch.cycles.features` and :mod:`hydrowatch.cycles.transients`):

- ``statistics``: the plain baseline (mean, spread, extremes, slope, phase means of every channel);
- ``transients``: values around each load change relative to their settled level, with the
  directions the other components' conditions move them projected out. The dimension of that
  projection is chosen on the training cycles only, by the honest split applied inside them
  (:func:`hydrowatch.cycles.splits.ordered_split`), unless given; optionally also as shares of each cycle's own
  step (``normalised``);
- ``entropy``: the study's method without a command (:mod:`hydrowatch.cycles.reference`): per sensor a
  healthy reference model, the relative entropy of each cycle's errors to each condition's.

The decision is LDA's, or (``discriminants``) reduced-rank LDA's in the leading discriminant directions only;
optionally (``trees``) its probabilities are averaged with those of a forest of extremely randomised trees on the
plain statistics, weighted ``tree_weight`` to 1, on the cycles whose operating condition the training cycles cover
(:class:`hydrowatch.cycles.trees.CoveredVote`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

from hydrowatch.cycles.features import cycle_statistics
from hydrowatch.cycles.linear import LinearDiscriminant
from hydrowatch.cycles.reference import CycleReferenceEntropy
from hydrowatch.cycles.splits import ordered_split
from hydrowatch.cycles.transients import LoadChangeTransients, NuisanceProjection
from hydrowatch.cycles.trees import CoveredVote
from hydrowatch.errors import NotFittedError, ParameterError

FEATURES = ("statistics", "transients", "entropy")
DIRECTIONS_GRID: tuple[int, ...] = (0, 1, 2, 3, 4, 6, 8, 10)
"""Nuisance dimensions tried when ``directions`` is None (the fewest among the best on validation wins)."""


class ComponentClassifier:
    """Classify one component's condition from whole cycles.

    Parameters
    ----------
    features : str, default "statistics"
        One of :data:`FEATURES`.
    grid_hz : float, default 1.0
        Sample rate of the cycles' last axis, Hz.
    phases : int, default 6
        Phase means per channel (``statistics``).
    reference : int, default 0
        Channel locating the load changes (``transients``).
    threshold : float, default 3.0
        Smallest jump of the reference's mean profile counted as a load change, its unit.
    directions : int or None, default None
        Nuisance dimensions removed (``transients``); None chooses from :data:`DIRECTIONS_GRID`.
    channels : sequence of int or None, default None
        Channels (axis 1) the features are made of; None: every channel. For ``transients`` the
        slow channels (temperatures) have no load-change dynamics and only add noise; the
        ``reference`` channel need not be among them. For ``entropy``: the sensors that get a reference model
        (every channel is an input).
    healthy : str or float or None, default None
        The component's healthy label (``entropy`` fits its reference models on those cycles; required there).
    normalised : bool, default False
        ``transients`` also as shares of each cycle's own step (:class:`LoadChangeTransients`).
    discriminants : int or None, default None
        Decide in the leading ``discriminants`` discriminant directions only (reduced-rank LDA: the nearest
        class centroid there, Mahalanobis, plus the log prior); None: all ``n_classes - 1`` (plain LDA).
        Ordered conditions (an accumulator's precharge levels) lie along the leading directions; the last ones
        separate them by small, condition-sensitive differences that a new operating condition overturns.
    trees : int, default 0
        Trees of a forest of extremely randomised trees (scikit-learn ``ExtraTreesClassifier``, seed 0) fitted on
        the plain statistics of every channel, whose probabilities vote with the linear decision's on the cycles
        whose operating condition (the other components' levels, read from the cycle) the training cycles cover
        for every state (:class:`~hydrowatch.cycles.trees.CoveredVote`); 0: no vote. The linear decision
        extrapolates to conditions its training lacks but is rigid; the forest interpolates the conditions it has
        seen, the odd cycles among them.
    tree_weight : float, default 1.0
        The forest's weight; the vote is ``(p_linear + tree_weight · p_forest) / (1 + tree_weight)``.
    coverage : int, default 10
        Training cycles of every state a level of another component needs for the vote to count there.
    """

    def __init__(
        self,
        *,
        features: str = "statistics",
        grid_hz: float = 1.0,
        phases: int = 6,
        reference: int = 0,
        threshold: float = 3.0,
        directions: int | None = None,
        channels: Sequence[int] | None = None,
        healthy: str | float | None = None,
        normalised: bool = False,
        discriminants: int | None = None,
        trees: int = 0,
        tree_weight: float = 1.0,
        coverage: int = 10,
    ) -> None:
        self.features = features
        self.grid_hz = grid_hz
        self.phases = phases
        self.reference = reference
        self.threshold = threshold
        self.directions = directions
        self.channels = channels
        self.healthy = healthy
        self.normalised = normalised
        self.discriminants = discriminants
        self.trees = trees
        self.tree_weight = tree_weight
        self.coverage = coverage

    def _fit_once(
        self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, directions: int
    ) -> tuple[LoadChangeTransients | None, NuisanceProjection | None, CycleReferenceEntropy | None,
               LinearDiscriminant]:
        if self.features == "statistics":
            x = self._statistics(values)
            lda = make_pipeline(StandardScaler(), LinearDiscriminantAnalysis()).fit(x, labels)
            return None, None, None, LinearDiscriminant.from_fitted(lda)
        if self.features == "entropy":
            if self.healthy is None:
                raise ParameterError("healthy must be the component's healthy label for features='entropy'. Got None.")
            entropy = CycleReferenceEntropy(healthy=self.healthy, sensors=self.channels).fit(values, labels)
            lda = make_pipeline(StandardScaler(), LinearDiscriminantAnalysis()).fit(entropy.transform(values), labels)
            return None, None, entropy, LinearDiscriminant.from_fitted(lda)
        transients = LoadChangeTransients(
            reference=self.reference, threshold=self.threshold, channels=self.channels, normalised=self.normalised
        ).fit(values)
        x = transients.transform(values)
        projection = NuisanceProjection(directions=directions).fit(x, labels, nuisance)
        lda = LinearDiscriminantAnalysis().fit(projection.transform(x), labels)
        return transients, projection, None, LinearDiscriminant.from_fitted(lda)

    def fit(self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray | None = None) -> ComponentClassifier:
        """Fit on training cycles.

        Parameters
        ----------
        values : ndarray, shape (n_cycles, n_channels, n_samples)
            Cycles on the grid, in recording order (the choice of ``directions`` relies on it).
        labels : ndarray, shape (n_cycles,)
            The component's condition per cycle.
        nuisance : ndarray, shape (n_cycles, n_others), optional
            The other components' conditions (``transients``); none: nothing is projected out.
        """
        if self.features not in FEATURES:
            raise ParameterError(f"features must be one of {list(FEATURES)}. Got {self.features!r}.")
        if self.discriminants is not None and self.discriminants < 1:
            raise ParameterError(f"discriminants must be >= 1 or None. Got {self.discriminants}.")
        if self.trees < 0 or self.tree_weight < 0 or self.coverage < 1:
            raise ParameterError(f"trees and tree_weight must be >= 0 and coverage >= 1. Got {self.trees}, "
                                 f"{self.tree_weight}, {self.coverage}.")
        if nuisance is None:
            nuisance = np.zeros((len(labels), 1))
        # one BLAS thread: the discriminants' SVDs are ~1000 x ~300; on 2 busy cores OpenBLAS's spinning threads made
        # each take 1-6 s instead of 0.03-0.08 s (the UCI rig's honest split: 167 of 190 s in SVDs)
        with threadpool_limits(limits=1, user_api="blas"):
            directions = self.directions
            if directions is None:
                directions = self.choose_directions(values, labels, nuisance) if self.features == "transients" else 0
            self.directions_ = directions
            self.classes_ = np.unique(labels)
            self.transients_, self.projection_, self.entropy_, self.model_ = self._fit_once(
                values, labels, nuisance, directions)
            projected = self.model_.transform(self._features(values))
        self.centroids_ = np.stack([projected[labels == c].mean(axis=0) for c in self.classes_])
        self.priors_ = np.array([np.mean(labels == c) for c in self.classes_])
        self.vote_ = None if not self.trees else CoveredVote.fit(
            self._all_statistics(values), labels, nuisance, trees=self.trees, weight=self.tree_weight,
            coverage=self.coverage)
        return self

    def choose_directions(
        self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, grid: Sequence[int] = DIRECTIONS_GRID
    ) -> int:
        """Nuisance dimension with the best validation accuracy (fewest on ties, within 0.1 %).

        Validation: the honest split of the given (training) cycles, first 70 % of each class fit,
        last 30 % score.
        """
        fit_part, check = ordered_split(labels)
        scores = []
        for k in grid:
            transients, projection, _, model = self._fit_once(values[fit_part], labels[fit_part], nuisance[fit_part], k)
            x = self._transform(values[check], transients, projection)
            if self.discriminants is None:
                predicted = model.predict(x)
            else:
                classes = np.unique(labels[fit_part])
                projected = model.transform(self._transform(values[fit_part], transients, projection))
                centroids = np.stack([projected[labels[fit_part] == c].mean(axis=0) for c in classes])
                priors = np.array([np.mean(labels[fit_part] == c) for c in classes])
                predicted = classes[self._reduced_scores(model.transform(x), centroids, priors).argmax(axis=1)]
            scores.append(float(np.mean(predicted == labels[check])))
        self.validation_ = dict(zip(grid, scores, strict=True))
        best = max(scores)
        return next(k for k, s in zip(grid, scores, strict=True) if s >= best - 1e-3)

    def _all_statistics(self, values: np.ndarray) -> np.ndarray:
        return cycle_statistics(values, self.grid_hz, self.phases)

    def _statistics(self, values: np.ndarray) -> np.ndarray:
        chosen = values if self.channels is None else values[:, list(self.channels), :]
        return cycle_statistics(chosen, self.grid_hz, self.phases)

    def _transform(
        self, values: np.ndarray, transients: LoadChangeTransients | None, projection: NuisanceProjection | None
    ) -> np.ndarray:
        if transients is None or projection is None:
            return self._statistics(values)
        return projection.transform(transients.transform(values))

    def _features(self, values: np.ndarray) -> np.ndarray:
        if not hasattr(self, "model_"):
            raise NotFittedError("ComponentClassifier must be fitted before predict. Call fit first.")
        if self.entropy_ is not None:
            return self.entropy_.transform(values)
        return self._transform(values, self.transients_, self.projection_)

    def _reduced_scores(self, projected: np.ndarray, centroids: np.ndarray, priors: np.ndarray) -> np.ndarray:
        """Reduced-rank LDA's log posterior up to a constant: ``-d²/2 + log prior``, d the distance to each
        centroid in the leading ``discriminants`` coordinates; shape (n_cycles, n_classes)."""
        m = self.discriminants
        d2 = ((projected[:, None, :m] - centroids[None, :, :m]) ** 2).sum(axis=2)
        return np.asarray(-0.5 * d2 + np.log(priors)[None, :])

    def predict(self, values: np.ndarray) -> np.ndarray:
        """The condition of each cycle, shape (n_cycles,)."""
        if self.discriminants is None and getattr(self, "vote_", None) is None:  # unfitted: _features says so
            x = self._features(values)
            return np.asarray(self.model_.predict(x))
        return np.asarray(self.classes_[self.predict_proba(values).argmax(axis=1)])

    def predict_proba(self, values: np.ndarray) -> np.ndarray:
        """Probability of each class (``classes_`` order) per cycle, shape (n_cycles, n_classes); with
        ``discriminants``, the softmax of the reduced-rank scores; with ``trees``, the vote with the forest's."""
        x = self._features(values)
        if self.discriminants is None:
            p = np.asarray(self.model_.predict_proba(x))
        else:
            scores = self._reduced_scores(self.model_.transform(x), self.centroids_, self.priors_)
            e = np.exp(scores - scores.max(axis=1, keepdims=True))
            p = np.asarray(e / e.sum(axis=1, keepdims=True))
        return p if self.vote_ is None else self.vote_.combine(p, self._all_statistics(values))

    def distances(self, values: np.ndarray) -> np.ndarray:
        """Distance of each cycle to each class's training centroid in the discriminant space.

        LDA's discriminant coordinates whiten the pooled within-class covariance, so this is a
        Mahalanobis distance in the at most ``n_classes - 1`` discriminant directions.

        Returns
        -------
        ndarray, shape (n_cycles, n_classes)
            In ``classes_`` order, dimensionless.
        """
        projected = self.model_.transform(self._features(values))
        return np.asarray(np.linalg.norm(projected[:, None, :] - self.centroids_[None, :, :], axis=2))

    PARAMETERS: tuple[str, ...] = ("features", "grid_hz", "phases", "reference", "threshold", "directions",
                                   "channels", "healthy", "normalised", "discriminants", "trees", "tree_weight",
                                   "coverage")

    def to_state(self) -> dict[str, Any]:
        """Parameters and fitted arrays, no scikit-learn object (:mod:`hydrowatch.cycles.state` stores them)."""
        if not hasattr(self, "model_"):
            raise NotFittedError("ComponentClassifier must be fitted before to_state. Call fit first.")
        parameters = {k: getattr(self, k) for k in self.PARAMETERS}
        parameters["channels"] = None if self.channels is None else [int(c) for c in self.channels]
        return {"parameters": parameters, "directions_": int(self.directions_), "classes_": self.classes_,
                "centroids_": self.centroids_, "priors_": self.priors_, "model_": self.model_.to_state(),
                "transients_": None if self.transients_ is None else self.transients_.to_state(),
                "projection_": None if self.projection_ is None else self.projection_.to_state(),
                "entropy_": None if self.entropy_ is None else self.entropy_.to_state(),
                "vote_": None if self.vote_ is None else self.vote_.to_state()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> ComponentClassifier:
        """The inverse of :meth:`to_state`."""
        out = cls(**state["parameters"])  # a model saved before 2026-11-26 lacks normalised and discriminants
        out.directions_, out.classes_, out.centroids_ = state["directions_"], state["classes_"], state["centroids_"]
        out.priors_ = state.get("priors_", np.full(len(out.classes_), 1.0 / len(out.classes_)))
        out.model_ = LinearDiscriminant.from_state(state["model_"])
        out.transients_ = None if state["transients_"] is None else LoadChangeTransients.from_state(
            state["transients_"])
        out.projection_ = None if state["projection_"] is None else NuisanceProjection.from_state(
            state["projection_"])
        out.entropy_ = None if state["entropy_"] is None else CycleReferenceEntropy.from_state(state["entropy_"])
        vote = state.get("vote_")  # a model saved before the trees' vote (format 2) has none
        out.vote_ = None if vote is None else CoveredVote.from_state(vote)
        return out
