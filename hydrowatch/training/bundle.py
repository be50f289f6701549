"""A model bundle: one fitted health method + a JSON manifest, in one directory.

Layout::

    MODEL_DIR/
      manifest.json         format, version, method, reference kind, states, sensors, window, data, metrics
      ...                   the method's own files (:meth:`HealthMethod.save
                            <hydrowatch.methods.base.HealthMethod.save>`): entropy ``reference/`` and
                            ``health/``, parity ``condition/``, stats ``stats/`` (docs/architecture.md)

A folder of several bundles (``train --method both|all``) holds ``<key>/`` per bundle and
``bundles.json`` naming the default one, which :meth:`ModelBundle.load` takes for the folder.

A manifest without ``method`` (written before the parity method existed) is an ``entropy`` bundle.

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

from hydrowatch.condition import ConditionModel
from hydrowatch.errors import DataError
from hydrowatch.methods import method_class
from hydrowatch.methods.base import HealthMethod

FORMAT = "hydrowatch.model_bundle"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
INDEX = "bundles.json"
"""Index of a folder of several bundles (``train --method both|all``): ``{"default": KEY, "bundles": [KEY, ...]}``."""


@dataclass
class ModelBundle:
    """Everything the scorer needs.

    Attributes
    ----------
    health_method : HealthMethod
        The fitted method (:mod:`hydrowatch.methods`).
    manifest : dict
        ``format``, ``format_version``, ``version``, ``method``, ``reference``, ``states``,
        ``sensors``, ``window`` (samples), ``hop``, ``warmup``, ``data`` and ``metrics``.
    """

    health_method: HealthMethod
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def method(self) -> str:
        """Name of the bundle's method (``parity``, ``entropy``, …)."""
        return self.health_method.name

    @property
    def sensors(self) -> list[str]:
        """Sensors the model reads."""
        return self.health_method.sensors

    @property
    def kl_rows(self) -> list[str]:
        """Rows of a window's ``kl`` scores: sensors (relative entropies), relations (parity scores), …"""
        return self.health_method.kl_rows

    @property
    def states(self) -> list[str]:
        """Trained health states, in the decision's order."""
        return self.health_method.states

    @property
    def window(self) -> int:
        """Samples per window."""
        return self.health_method.window

    @property
    def hop(self) -> int:
        """Samples between window starts."""
        return self.health_method.hop

    @property
    def warmup(self) -> int:
        """Samples before the first window (the reference models' warm-up; 0 for methods without one)."""
        return self.health_method.warmup

    @property
    def condition(self) -> ConditionModel | None:
        """The condition model of a parity bundle (None for other methods); kept for scripts and tests that read it."""
        model = getattr(self.health_method, "model", None)
        return model if isinstance(model, ConditionModel) else None

    @property
    def version(self) -> str:
        """Model version carried by every verdict (registry version or content hash)."""
        return str(self.manifest.get("version", "unversioned"))

    def save(self, directory: str | Path) -> Path:
        """Write the bundle; the manifest's ``version`` becomes a hash of the model files."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        files = self.health_method.save(d)
        digest = hashlib.sha256()
        for f in sorted(files):
            digest.update(f.read_bytes())
        self.manifest.update({"format": FORMAT, "format_version": FORMAT_VERSION, "method": self.method,
                              "version": f"sha256:{digest.hexdigest()[:12]}"})
        (d / MANIFEST).write_text(json.dumps(self.manifest, indent=1, default=_plain))
        return d

    @classmethod
    def load(cls, directory: str | Path, *, version: str | None = None) -> ModelBundle:
        """Read a bundle directory; ``version`` overrides the manifest's (e.g. a registry version)."""
        d = Path(directory)
        if not (d / MANIFEST).exists() and (d / INDEX).exists():
            d = d / _default_bundle(d)
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
        if version is not None:
            manifest["version"] = version
        return cls(method_class(manifest.get("method", "entropy")).load(d, manifest), manifest)


def write_index(directory: str | Path, keys: list[str]) -> Path:
    """Write ``directory/bundles.json`` for the bundles in ``directory/<key>``; the last key is the default."""
    path = Path(directory) / INDEX
    path.write_text(json.dumps({"default": keys[-1], "bundles": keys}, indent=1))
    return path


def _default_bundle(directory: Path) -> str:
    try:
        index = json.loads((directory / INDEX).read_text())
        key = str(index["default"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise DataError(f"{INDEX} must be JSON with a 'default' bundle. Got: {exc}.", str(directory / INDEX)) from None
    if not (directory / key / MANIFEST).exists():
        raise DataError(f"the default bundle {key!r} named in {INDEX} must be a bundle folder beside it "
                        f"(with {MANIFEST}). It is missing; retrain with `hydrowatch train`.", str(directory / INDEX))
    return key


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
