"""Health statistics: base prediction-error distributions, relative entropy per window, classifier, verdicts.

Study chapters 5 and 6: per sensor the reference model's prediction errors (Eq. 5.1) of each
window are compared with each health state's base distribution by relative entropy (Eq. 5.2,
5.3); a small network fuses the sensors x states relative entropies into a health state. See
docs/health.md. The verdict type every method returns is :class:`hydrowatch.verdict.Verdict`.
"""

from hydrowatch.health.classifier import HealthClassifier, stratified_split
from hydrowatch.health.distributions import GaussianBase, Mixture, MixtureBase, fit_gaussian, fit_mixture
from hydrowatch.health.entropy import gaussian_relative_entropy, mixture_relative_entropy, monte_carlo_relative_entropy
from hydrowatch.health.features import RelativeEntropyFeatures, log_features
from hydrowatch.health.metrics import accuracy, confusion_matrix, expected_calibration_error, per_class_recall
from hydrowatch.health.model import HealthModel
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.health.plan import DataPlan, StateSplit, split_state
from hydrowatch.health.streaming import EntropyWindow, MachineWindow, WindowResult
from hydrowatch.health.verdict import judge
from hydrowatch.health.windows import sliding_windows, window_starts

__all__ = [
    "DataPlan", "EntropyWindow", "GaussianBase", "HealthClassifier", "HealthModel",
    "MachineWindow", "Mixture", "MixtureBase", "OpenSetRule", "RelativeEntropyFeatures", "StateSplit",
    "WindowResult", "accuracy", "confusion_matrix", "expected_calibration_error", "fit_gaussian",
    "fit_mixture", "gaussian_relative_entropy", "judge", "log_features", "mixture_relative_entropy",
    "monte_carlo_relative_entropy", "per_class_recall", "sliding_windows", "split_state", "stratified_split",
    "window_starts",
]
