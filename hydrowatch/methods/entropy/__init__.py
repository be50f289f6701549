"""The study's method: healthy reference models per sensor, relative entropies of their errors, a classifier.

Bundle folder::

    reference/<sensor>.narx.pt | <sensor>.bj.json    one reference model per sensor (:mod:`.reference`)
    health/                                          base_distributions.json, classifier.npz, open_set.json

Training is :mod:`.train`, streaming :mod:`.online`; the maths is in :mod:`hydrowatch.sysid` and
:mod:`hydrowatch.health`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from hydrowatch.health.model import HealthModel
from hydrowatch.methods.base import HealthMethod, MethodFit, OfflineScores
from hydrowatch.methods.entropy.online import EntropyEngine
from hydrowatch.methods.entropy.reference import SensorReference
from hydrowatch.recording import INPUT, Recording

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings


class EntropyMethod(HealthMethod):
    """The study's method, fitted (module docstring).

    Parameters
    ----------
    references : dict of str to SensorReference
        One fitted reference model per sensor, in sensor order.
    health : HealthModel
        Fitted base distributions, classifier and open-set rule.
    reference : {"narx", "bj"}
        Kind of the reference models.
    """

    name: ClassVar[str] = "entropy"

    def __init__(self, references: dict[str, SensorReference], health: HealthModel, reference: str) -> None:
        self.references = references
        self.health = health
        self.reference = reference

    @classmethod
    def fit(cls, grouped: Mapping[str, list[Recording]], settings: TrainingSettings) -> MethodFit:
        """Reference models on the healthy data, then the health model (:func:`.train.fit_entropy`)."""
        from hydrowatch.methods.entropy.train import fit_entropy

        refs, health, got = fit_entropy(grouped, settings)
        return MethodFit(cls(refs, health, settings.reference), got["manifest"], got["entropies"], got["evaluation"],
                         got["base"], got["reference"])

    @classmethod
    def settings_dict(cls, settings: TrainingSettings) -> dict[str, Any]:
        """``method``, ``reference``, ``distribution``, ``classifier_hidden``, ``seed`` and ``<reference>.<param>``."""
        out: dict[str, Any] = {"method": cls.name, "reference": settings.reference,
                               "distribution": settings.distribution, "classifier_hidden": settings.hidden,
                               "seed": settings.seed}
        out.update({f"{settings.reference}.{k}": v for k, v in settings.reference_params().items()})
        return out

    @classmethod
    def run_name(cls, settings: TrainingSettings) -> str:
        """The reference kind: ``narx`` or ``bj``."""
        return settings.reference

    @classmethod
    def load(cls, directory: Path, manifest: Mapping[str, Any]) -> EntropyMethod:
        """Reference models of the manifest's ``sensors`` (kind ``reference``) and the health model."""
        kind = manifest["reference"]
        references = {s: SensorReference.load(directory / "reference", s, kind) for s in manifest["sensors"]}
        return cls(references, HealthModel.load(directory / "health"), kind)

    def save(self, directory: Path) -> list[Path]:
        """``reference/`` and ``health/`` under ``directory``."""
        (directory / "reference").mkdir(parents=True, exist_ok=True)
        files = [ref.save(directory / "reference") for ref in self.references.values()]
        self.health.save(directory / "health")
        return files + list((directory / "health").iterdir())

    @property
    def headline(self) -> str:
        """``Reference models: <kind>``."""
        return f"Reference models: {self.reference}"

    @property
    def table_caption(self) -> str:
        """The relative entropies' caption (the study's table 6.1)."""
        return ("Median relative entropy of each state's windows against every base distribution (nats), "
                "as the study's table 6.1:")

    @property
    def sensors(self) -> list[str]:
        """Sensors with a reference model, in the order of the prediction-error columns."""
        return list(self.references)

    @property
    def states(self) -> list[str]:
        """Trained health states, in the classifier's order."""
        return list(self.health.features_.states_)

    @property
    def window(self) -> int:
        """Samples per window."""
        return int(self.health.features_.window)

    @property
    def hop(self) -> int:
        """Samples between window starts."""
        return int(self.health.features_.hop)

    @property
    def warmup(self) -> int:
        """Samples before every sensor's prediction errors count."""
        return max((r.warmup_ for r in self.references.values()), default=0)

    def errors(self, recording: Recording) -> np.ndarray:
        """Prediction errors of every sensor, shape (n, n_sensors); NaN rows during warm-up."""
        u = recording[INPUT]
        return np.column_stack([ref.errors(u, recording[s]) for s, ref in self.references.items()])

    def score(self, recording: Recording, smoothing: int = 1) -> OfflineScores:
        """Windows of the prediction errors after the warm-up; ``kl``: relative entropies per sensor and state."""
        errors = self.errors(recording)[self.warmup:]
        starts, verdicts = self.health.score(errors)
        return OfflineScores(starts, verdicts, self.health.features_.window_entropies(errors))

    def online(self, *, smoothing: int = 1,
               unit_method: Callable[[str], HealthMethod | None] | None = None) -> EntropyEngine:
        """:class:`~.online.EntropyEngine` (each machine's reference-model states; windows of their errors)."""
        return EntropyEngine(list(self.references.values()), self.health, self.sensors)

    def commission(self, recordings: list[Recording]) -> tuple[EntropyMethod, dict[str, Any]]:
        """Refused: the base distributions would need the unit's own fault recordings."""
        from hydrowatch.condition.commission import CommissioningError

        raise CommissioningError("commissioning adapts parity bundles (train --method parity, the default). Got an "
                                 "entropy bundle: its base distributions need the unit's own fault recordings; "
                                 "train it on this unit instead.")
