"""Command-invariant health features from the component relations of the nominal plant (issue 5).

Public API: :class:`ConditionFeatures` (raw windows → per-state parity scores),
:func:`windows_from_recording` (a recording's raw windows, :mod:`hydrowatch.condition.estimates`),
:class:`ConditionModel` (features + decision + open-set rule),
and the evidence pooled over a machine's recent windows (:class:`ConditionStream`,
:class:`EvidenceSmoother`, :func:`trailing_evidence`).
The relations themselves are in :mod:`hydrowatch.condition.parity`; docs/command-invariance.md
has the measurements.
"""

from hydrowatch.condition.evidence import EvidenceLayout, EvidenceSmoother, pooled_windows, trailing_evidence
from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.condition.layout import windows_from_recording
from hydrowatch.condition.model import ConditionModel
from hydrowatch.condition.rule import ParityRule
from hydrowatch.condition.stream import ConditionStream

__all__ = ["ConditionFeatures", "ConditionModel", "ConditionStream", "EvidenceLayout", "EvidenceSmoother", "ParityRule",
           "pooled_windows", "trailing_evidence", "windows_from_recording"]
