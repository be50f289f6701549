"""A fitted forest of decision trees as plain arrays, and its vote where the training cycles cover a cycle's operating
condition: :class:`~hydrowatch.cycles.ComponentClassifier`'s ``trees`` option.

scikit-learn fits it (``ExtraTreesClassifier``, or any forest of ``DecisionTreeClassifier``); :meth:`TreeForest.
from_fitted` keeps only the trees' arrays, so a bundle stores it as JSON (:mod:`hydrowatch.cycles.state`) instead of a
pickle. The maths are scikit-learn's (version 1.x, ``sklearn/tree/_tree.pyx`` and ``sklearn/ensemble/_forest.py``):

- a tree sends a row left at a node when ``float32(x[feature]) <= threshold`` (scikit-learn compares the features as
  float32 with a float64 threshold), right otherwise, until a leaf (no left child);
- a tree's probabilities are its leaf's class weights divided by their sum (stored as float32, so within about
  1e-7 of scikit-learn's); the forest's the mean over its trees.

:class:`CoveredVote` lets the forest vote only for cycles whose operating condition the training cycles cover for
every state of the judged component (docs/rigs.md, "Random folds and the honest split at once").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.ensemble import ExtraTreesClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from hydrowatch.cycles.linear import LinearDiscriminant
from hydrowatch.errors import ParameterError


@dataclass(eq=False, kw_only=True)
class TreeForest:
    """A fitted forest of classification trees, as arrays (all trees' nodes one after the other).

    Parameters
    ----------
    classes : ndarray, shape (n_classes,)
        Class labels, in the order of the probability columns.
    roots : ndarray of int, shape (n_trees,)
        Index of each tree's first node.
    left, right : ndarray of int, shape (n_nodes,)
        Children of each node (indices into these arrays); -1 at a leaf.
    feature : ndarray of int, shape (n_nodes,)
        Feature (column) a node splits on; unused at a leaf.
    threshold : ndarray of float64, shape (n_nodes,)
        A row goes left when its feature, as float32, is at most this.
    leaf_probabilities : ndarray, shape (n_nodes, n_classes)
        Class probabilities of a row that ends at the node (its rows sum to 1 at leaves).
    """

    classes: np.ndarray
    roots: np.ndarray
    left: np.ndarray
    right: np.ndarray
    feature: np.ndarray
    threshold: np.ndarray
    leaf_probabilities: np.ndarray

    @classmethod
    def from_fitted(cls, forest: Any) -> TreeForest:
        """The arrays of a fitted scikit-learn forest classifier (single output)."""
        if getattr(forest, "n_outputs_", None) != 1 or not hasattr(forest, "estimators_"):
            raise ParameterError(f"forest must be a fitted single-output scikit-learn forest classifier. Got "
                                 f"{forest!r}.")
        roots, left, right, feature, threshold, values = [], [], [], [], [], []
        offset = 0
        for estimator in forest.estimators_:
            tree = estimator.tree_
            leaf = tree.children_left < 0
            roots.append(offset)
            left.append(np.where(leaf, -1, tree.children_left + offset))
            right.append(np.where(leaf, -1, tree.children_right + offset))
            feature.append(np.where(leaf, 0, tree.feature))
            threshold.append(tree.threshold)
            weights = tree.value[:, 0, :]
            values.append(weights / weights.sum(axis=1, keepdims=True))
            offset += tree.node_count
        return cls(classes=np.asarray(forest.classes_), roots=np.asarray(roots, dtype=np.int32),
                   left=np.concatenate(left).astype(np.int32), right=np.concatenate(right).astype(np.int32),
                   feature=np.concatenate(feature).astype(np.int32),
                   threshold=np.concatenate(threshold).astype(np.float64),
                   leaf_probabilities=np.concatenate(values).astype(np.float32))

    def leaves(self, x: np.ndarray) -> np.ndarray:
        """The leaf each row of ``x`` (n, n_features) reaches in each tree, shape (n, n_trees)."""
        x32 = np.asarray(x, dtype=np.float32)
        rows = np.arange(len(x32))[:, None]
        node = np.broadcast_to(self.roots, (len(x32), len(self.roots))).copy()
        while True:
            inner = self.left[node] >= 0
            if not inner.any():
                return node
            go_left = x32[rows, self.feature[node]] <= self.threshold[node]
            node = np.where(inner, np.where(go_left, self.left[node], self.right[node]), node)

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """Probability of each class (``classes`` order), shape (n, n_classes): the mean of the trees'."""
        return np.asarray(self.leaf_probabilities[self.leaves(x)].astype(np.float64).mean(axis=1))

    def to_state(self) -> dict[str, Any]:
        """Parameters and arrays (:mod:`hydrowatch.cycles.state`)."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> TreeForest:
        """The inverse of :meth:`to_state`."""
        return cls(**state)


@dataclass(eq=False, kw_only=True)
class CoveredVote:
    """A forest's class probabilities, voting only where the training cycles cover a cycle's operating condition.

    The operating condition is the levels of the *other* components (the nuisance columns a component's classifier
    is given), each read from the cycle's statistics by its own LDA. A level is **covered** when the training cycles
    hold at least ``coverage`` cycles of every state of the judged component at it; a cycle is covered when all its
    read levels are. There the forest (which interpolates what it has seen) votes with the linear decision; elsewhere
    the linear decision (built to extrapolate) stands alone: a forest weighted above it would read a state at a
    condition the training never showed it at as the state the training did show there.

    Parameters
    ----------
    forest : TreeForest
        Fitted on the statistics of the training cycles.
    weight : float
        The forest's weight: ``(p_linear + weight · p_forest) / (1 + weight)`` on covered cycles.
    level_models : list of LinearDiscriminant or None
        Per nuisance column, the LDA reading its level (None: one level only).
    levels : list of ndarray
        Per nuisance column, its levels (sorted).
    covered : list of ndarray of bool
        Per nuisance column, whether each level is covered.
    """

    forest: TreeForest
    weight: float
    level_models: list[LinearDiscriminant | None]
    levels: list[np.ndarray]
    covered: list[np.ndarray]

    @classmethod
    def fit(cls, statistics: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, *, trees: int, weight: float,
            coverage: int) -> CoveredVote:
        """Fit the forest (``trees`` extremely randomised trees, seed 0) and the level readers on training cycles.

        Parameters
        ----------
        statistics : ndarray, shape (n_cycles, n_features)
            The cycles' plain statistics.
        labels : ndarray, shape (n_cycles,)
            The judged component's state per cycle.
        nuisance : ndarray, shape (n_cycles, n_others)
            The other components' levels per cycle.
        """
        forest = ExtraTreesClassifier(n_estimators=trees, random_state=0, n_jobs=1).fit(statistics, labels)
        states = np.unique(labels)
        models: list[LinearDiscriminant | None] = []
        levels, covered = [], []
        for column in np.asarray(nuisance).T:
            values = np.unique(column)
            levels.append(values)
            covered.append(np.array([min(np.sum((column == v) & (labels == s)) for s in states) >= coverage
                                     for v in values]))
            models.append(None if values.size < 2 else LinearDiscriminant.from_fitted(
                make_pipeline(StandardScaler(), LinearDiscriminantAnalysis()).fit(statistics, column)))
        return cls(forest=TreeForest.from_fitted(forest), weight=weight, level_models=models, levels=levels,
                   covered=covered)

    def covered_cycles(self, statistics: np.ndarray) -> np.ndarray:
        """Whether each cycle's read operating condition is covered, shape (n_cycles,)."""
        out = np.ones(len(statistics), dtype=bool)
        for model, values, covered in zip(self.level_models, self.levels, self.covered, strict=True):
            read = np.full(len(statistics), values[0]) if model is None else model.predict(statistics)
            out &= covered[np.searchsorted(values, read)]
        return out

    def combine(self, linear: np.ndarray, statistics: np.ndarray) -> np.ndarray:
        """The vote: ``linear`` (n_cycles, n_classes) probabilities, with the forest's on covered cycles."""
        voted = (linear + self.weight * self.forest.predict_proba(statistics)) / (1.0 + self.weight)
        return np.asarray(np.where(self.covered_cycles(statistics)[:, None], voted, linear))

    def to_state(self) -> dict[str, Any]:
        """Parameters and arrays (:mod:`hydrowatch.cycles.state`)."""
        return {"forest": self.forest.to_state(), "weight": self.weight,
                "level_models": [None if m is None else m.to_state() for m in self.level_models],
                "levels": self.levels, "covered": self.covered}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> CoveredVote:
        """The inverse of :meth:`to_state`."""
        return cls(forest=TreeForest.from_state(state["forest"]), weight=state["weight"],
                   level_models=[None if m is None else LinearDiscriminant.from_state(m)
                                 for m in state["level_models"]],
                   levels=list(state["levels"]), covered=list(state["covered"]))
