"""The parity method: component relations of the nominal plant, a nearest-physics decision (issue 5).

Bundle folder::

    condition/          condition_features.json, decision.json (or classifier.npz), open_set.json,
                        condition_model.json (:meth:`ConditionModel.save`)

The manifest's ``temperature`` says whether the windows carry the oil temperature. Training is
:mod:`.train`, streaming :mod:`.online`; the maths is in :mod:`hydrowatch.condition`
(docs/command-invariance.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from hydrowatch.condition import ConditionModel, windows_from_recording
from hydrowatch.condition.degradation import features_degradation
from hydrowatch.condition.stream import POOLED_WINDOWS
from hydrowatch.methods.base import HealthMethod, MethodFit, OfflineScores, check_channels
from hydrowatch.methods.parity.online import ParityJudge
from hydrowatch.recording import Recording

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings


class ParityMethod(HealthMethod):
    """The parity method, fitted (module docstring).

    Parameters
    ----------
    model : ConditionModel
        Fitted parity features, decision and open-set rule.
    temperature : bool
        Whether the windows carry the oil temperature (5th column).
    """

    name: ClassVar[str] = "parity"
    pools: ClassVar[bool] = True
    default_smoothing: ClassVar[int] = POOLED_WINDOWS
    commissionable: ClassVar[bool] = True
    row_label: ClassVar[str] = "relation"

    def __init__(self, model: ConditionModel, temperature: bool) -> None:
        self.model = model
        self.temperature = temperature

    @classmethod
    def fit(cls, grouped: Mapping[str, list[Recording]], settings: TrainingSettings) -> MethodFit:
        """Raw windows of every state → :class:`ConditionModel` (:func:`.train.fit_parity`)."""
        from hydrowatch.methods.parity.train import fit_parity

        model, temperature, got = fit_parity(grouped, settings)
        return MethodFit(cls(model, temperature), got["manifest"], got["scores"], got["evaluation"])

    @classmethod
    def load(cls, directory: Path, manifest: Mapping[str, Any]) -> ParityMethod:
        """``condition/`` under ``directory``."""
        return cls(ConditionModel.load(directory / "condition"), bool(manifest.get("temperature")))

    def save(self, directory: Path) -> list[Path]:
        """``condition/`` under ``directory``."""
        self.model.save(directory / "condition")
        return list((directory / "condition").iterdir())

    @property
    def headline(self) -> str:
        """How the report introduces a parity run."""
        return "Parity method (component relations)"

    @property
    def table_caption(self) -> str:
        """The relation scores' caption."""
        return ("Median relation score F[r, k] of each state's test windows (1: state k's physics explains the "
                "relation as well as a free fit):")

    @property
    def sensors(self) -> list[str]:
        """Sensors the relations read."""
        return list(self.model.features_.sensors)

    @property
    def states(self) -> list[str]:
        """Trained health states."""
        return list(self.model.features_.states_)

    @property
    def kl_rows(self) -> list[str]:
        """The relations (``load``, ``motor``, ``valve``): rows of the relation scores F[r, k]."""
        return list(self.model.features_.relations_)

    @property
    def window(self) -> int:
        """Samples per window."""
        return int(self.model.features_.window)

    @property
    def hop(self) -> int:
        """Samples between window starts (= window: windows do not overlap)."""
        return int(self.model.features_.hop)

    def score(self, recording: Recording, smoothing: int = 1) -> OfflineScores:
        """Raw windows from the first sample; ``kl``: relation scores; the degradation index of every window."""
        model = self.model
        temperature = self.temperature and "temperature" in recording.channels
        raw = windows_from_recording(recording, self.window, self.hop, temperature=temperature)
        rows, valid, estimates = model.features_.evidence_and_estimates(raw)  # one fit of the relations serves all
        verdicts, scores = model.judge_with_scores(raw, smoothing, rows)
        starts = model.features_.window_starts(len(recording))
        return OfflineScores(starts, verdicts, scores.reshape(scores.shape[0], len(self.kl_rows), len(self.states)),
                             features_degradation(model.features_, raw, estimated=(valid, estimates)))

    def online(self, *, smoothing: int = 1,
               unit_method: Callable[[str], HealthMethod | None] | None = None) -> ParityJudge:
        """:class:`~.online.ParityJudge`; ``unit_method`` gives a machine's commissioned parity method."""
        unit_model = None if unit_method is None else (lambda machine: _model_of(unit_method(machine)))
        return ParityJudge(self.model, self.temperature, self.window, self.hop, smoothing=smoothing,
                           unit_model=unit_model)

    def commission(self, recordings: list[Recording]) -> tuple[ParityMethod, dict[str, Any]]:
        """The model moved to one unit's parameters (:func:`hydrowatch.condition.commission.commission`).

        Raises
        ------
        CommissioningError
            When the recordings cannot commission the unit (too short, a command that never loads the parts, a
            fault already present, no temperature although the model reads it).
        DataError
            When a recording lacks a sensor the model reads (naming it).
        """
        from hydrowatch.condition.commission import CommissioningError, commission

        parts = []
        for rec in recordings:
            check_channels(self, rec)  # a sensor the model reads, missing: named
            if self.temperature and "temperature" not in rec.channels:
                raise CommissioningError("the recording must carry 'temperature': the model was trained with it. "
                                         f"Got channels {sorted(rec.channels)}.",
                                         str(rec.meta.get("source", "")) or None)
            parts.append(windows_from_recording(rec, self.window, self.hop, temperature=self.temperature))
        windows = np.concatenate(parts) if parts else np.empty((0, self.window, 4))
        result = commission(self.model, windows)
        return ParityMethod(result.model, self.temperature), result.summary()


def _model_of(method: HealthMethod | None) -> ConditionModel | None:
    return method.model if isinstance(method, ParityMethod) else None
