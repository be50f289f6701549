"""What training returns, whatever the health method: the bundle and what was measured on the way.

Shared by the trainers, the pipeline (MLflow), the reports and the demo, so it lives in no
method's module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the bundle's type only: results sit below training in the import layers
    from hydrowatch.training.bundle import ModelBundle


@dataclass
class TrainingResult:
    """A trained bundle with what was measured on the way.

    Attributes
    ----------
    bundle : ModelBundle
    base_errors : dict of str to ndarray, shape (n_k, n_sensors)
        Prediction errors of each state's base part (figures 6.1-6.3); empty for the parity method.
    window_entropies : dict of str to ndarray, shape (m_k, n_rows, n_states)
        Relative entropies of each state's classifier windows (table 6.1 is one such window), rows
        the sensors; for the parity method the relation scores of the test windows, rows the relations.
    evaluation : dict
        ``test_accuracy``, ``per_class_recall``, ``confusion_matrix`` (true rows), ``labels``, ...
    reference : dict
        Empty for the parity method, else per sensor: ``nrmse_one_step``, the model summary (γ for
        NARX; Q, S, roots for Box-Jenkins) and ``correlations`` of the healthy base part's errors
        (Eqs. 4.22, 4.23: ``acf`` lags 0..20, ``ccf`` with the voltage lags -20..20, ``bound``).
    seconds : float
        Wall-clock training time, s.
    """

    bundle: ModelBundle
    base_errors: dict[str, np.ndarray]
    window_entropies: dict[str, np.ndarray]
    evaluation: dict[str, Any]
    reference: dict[str, Any]
    seconds: float

    def summary(self) -> dict[str, Any]:
        """The JSON summary ``hydrowatch train`` prints."""
        return {
            "version": self.bundle.version, "method": self.bundle.method,
            "reference": self.bundle.manifest["reference"],
            "states": self.bundle.states, "sensors": self.bundle.sensors,
            "nrmse_one_step": {s: r["nrmse_one_step"] for s, r in self.reference.items()},
            "test_accuracy": self.evaluation["test_accuracy"],
            "per_class_recall": self.evaluation["per_class_recall"],
            "test_windows": self.evaluation["test_windows"], "seconds": round(self.seconds, 1),
        }
