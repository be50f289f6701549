"""Command-invariant health features from the component relations of the nominal plant (issue 5).

Public API: :class:`ConditionFeatures` (raw windows → per-state parity scores), its helper
:func:`windows_from_recording`, and :class:`ConditionModel` (features + decision + open-set rule).
The relations themselves are in :mod:`hydrowatch.condition.parity`; docs/command-invariance.md
has the measurements.
"""

from hydrowatch.condition.features import ConditionFeatures, windows_from_recording
from hydrowatch.condition.model import ConditionModel, ParityRule

__all__ = ["ConditionFeatures", "ConditionModel", "ParityRule", "windows_from_recording"]
