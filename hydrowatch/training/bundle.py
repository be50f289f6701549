"""A model bundle: reference models + health model + a JSON manifest, in one directory.

Layout::

    MODEL_DIR/
      manifest.json         format, version, reference kind, states, sensors, window, data summary, metrics
      reference/<sensor>.narx.pt | <sensor>.bj.json
      health/               base_distributions.json, classifier.npz, open_set.json

A bundle is loaded from its directory or from the MLflow model registry (``models:/NAME@ALIAS``
or ``models:/NAME/VERSION``; the tracking URI as in :func:`hydrowatch.training.tracking.tracking_uri`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.errors import DataError
from hydrowatch.health.model import HealthModel
from hydrowatch.recording import INPUT, Recording
from hydrowatch.training.reference import SensorReference

FORMAT = "hydrowatch.model_bundle"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"


@dataclass
class ModelBundle:
    """Everything the scorer needs.

    Attributes
    ----------
    references : dict of str to SensorReference
        One fitted reference model per sensor, in sensor order.
    health : HealthModel
        Fitted base distributions, classifier and open-set rule.
    manifest : dict
        ``format``, ``format_version``, ``version``, ``reference``, ``states``, ``sensors``,
        ``window`` (samples), ``hop``, ``warmup``, ``data`` and ``metrics``.
    """

    references: dict[str, SensorReference]
    health: HealthModel
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def sensors(self) -> list[str]:
        """Sensors in the order of the prediction-error columns."""
        return list(self.references)

    @property
    def states(self) -> list[str]:
        """Trained health states, in the classifier's order."""
        return list(self.health.features_.states_)

    @property
    def warmup(self) -> int:
        """Samples before every sensor's prediction errors count."""
        return max(r.warmup_ for r in self.references.values())

    @property
    def version(self) -> str:
        """Model version carried by every verdict (registry version or content hash)."""
        return str(self.manifest.get("version", "unversioned"))

    def errors(self, recording: Recording) -> np.ndarray:
        """Prediction errors of every sensor, shape (n, n_sensors); NaN rows during warm-up."""
        u = recording[INPUT]
        return np.column_stack([ref.errors(u, recording[s]) for s, ref in self.references.items()])

    def save(self, directory: str | Path) -> Path:
        """Write the bundle; the manifest's ``version`` becomes a hash of the model files."""
        d = Path(directory)
        (d / "reference").mkdir(parents=True, exist_ok=True)
        files = [ref.save(d / "reference") for ref in self.references.values()]
        self.health.save(d / "health")
        digest = hashlib.sha256()
        for f in sorted([*files, *(d / "health").iterdir()]):
            digest.update(f.read_bytes())
        self.manifest.update({"format": FORMAT, "format_version": FORMAT_VERSION,
                              "version": f"sha256:{digest.hexdigest()[:12]}"})
        (d / MANIFEST).write_text(json.dumps(self.manifest, indent=1, default=_plain))
        return d

    @classmethod
    def load(cls, directory: str | Path, *, version: str | None = None) -> ModelBundle:
        """Read a bundle directory; ``version`` overrides the manifest's (e.g. a registry version)."""
        d = Path(directory)
        try:
            manifest = json.loads((d / MANIFEST).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"a model bundle must hold a readable {MANIFEST}. Got: {exc}.", str(d)) from None
        if manifest.get("format") != FORMAT or manifest.get("format_version") != FORMAT_VERSION:
            raise DataError(
                f"manifest format must be {FORMAT} v{FORMAT_VERSION}. Got {manifest.get('format')} "
                f"v{manifest.get('format_version')}. Retrain with `hydrowatch train`.",
                str(d),
            )
        kind = manifest["reference"]
        references = {s: SensorReference.load(d / "reference", s, kind) for s in manifest["sensors"]}
        if version is not None:
            manifest["version"] = version
        return cls(references, HealthModel.load(d / "health"), manifest)


def load_bundle(model: str | Path, tracking_uri: str | None = None) -> ModelBundle:
    """A bundle from a directory or a registry URI ``models:/NAME@ALIAS`` / ``models:/NAME/VERSION``."""
    text = str(model)
    if not text.startswith("models:/"):
        return ModelBundle.load(text)
    from hydrowatch.training.tracking import download_registered

    folder, version = download_registered(text, tracking_uri)
    return ModelBundle.load(folder, version=version)


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
