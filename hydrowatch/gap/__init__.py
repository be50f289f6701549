"""Sim-to-real gap analysis: calibrate the nominal model, locate its error, name the missing physics.

``GapAnalyser().fit(recording).report_`` is the contract's ``hydrowatch gap`` report; see
docs/gap.md for the method, the report's additions and the saved model format.
"""

from hydrowatch.gap.analysis import GapAnalyser, Unidentified, analyse_gap
from hydrowatch.gap.candidates import CANDIDATES, Candidate
from hydrowatch.gap.discrepancy import Discrepancy, GapModel, load_model
from hydrowatch.gap.relations import RELATIONS, RelationCheck, check_relations
from hydrowatch.gap.report import MODEL_SCHEMA, read_model
from hydrowatch.gap.second_opinion import TERM_EFFECTS, SecondOpinion, StabilitySelection, second_opinion
from hydrowatch.gap.space import CALIBRATED

__all__ = ["CALIBRATED", "CANDIDATES", "MODEL_SCHEMA", "RELATIONS", "TERM_EFFECTS", "Candidate", "Discrepancy",
           "GapAnalyser", "GapModel", "RelationCheck", "SecondOpinion", "StabilitySelection", "Unidentified",
           "analyse_gap", "check_relations", "load_model", "read_model", "second_opinion"]
