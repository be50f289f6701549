"""Commissioning bundles: a fleet's model bundle adapted to one machine, stored and found per machine id.

:func:`commission_bundle` turns a parity bundle and healthy recordings of one machine into that
machine's bundle (:meth:`HealthMethod.commission <hydrowatch.methods.base.HealthMethod.commission>`,
for parity :func:`hydrowatch.condition.commission.commission`); its manifest gains

    "commissioned": {"machine": ID, "base_version": FLEET_VERSION, "sources": [...], "unit": {...}}

A folder of commissionings (``hydrowatch commission --out FOLDER/ID`` for each machine), or the
MLflow registry (``commission --register hydrowatch-ID``: a run in experiment
``hydrowatch-commissioning`` and a registered model with alias ``champion``), is read by
:class:`Commissionings`, which the scorer service uses to judge each machine with its own
bundle and to fall back to the fleet bundle, with a logged warning, for a machine it has none
for or one commissioned from another fleet version.

The study's method (entropy bundles) is refused: its base distributions are prediction-error
distributions of the trained unit's reference model in each health state, and a reference model
refitted on another unit's healthy data would need that unit's fault recordings to rebuild them.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from hydrowatch.condition.commission import CommissioningError
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger
from hydrowatch.recording import Recording
from hydrowatch.training.bundle import MANIFEST, ModelBundle, load_bundle

_log = get_logger(__name__)


def commission_bundle(bundle: ModelBundle, recordings: list[Recording], machine: str) -> ModelBundle:
    """The fleet ``bundle`` adapted to ``machine`` from its healthy ``recordings`` (not yet saved).

    Raises
    ------
    CommissioningError
        For a method that cannot be commissioned (entropy), an empty machine id, or recordings that cannot
        commission the unit (too short, a command that never loads the parts, a fault already present).
    """
    if not machine.strip():
        raise CommissioningError("--machine must name the machine (its id in the plant's messages). Got ''.")
    method, unit = bundle.health_method.commission(recordings)
    manifest: dict[str, Any] = copy.deepcopy(bundle.manifest)
    manifest.pop("version", None)
    sources = [str(r.meta.get("source", "")) for r in recordings]
    manifest["commissioned"] = {"machine": machine, "base_version": bundle.version, "sources": sources,
                                "unit": unit}
    return ModelBundle(method, manifest)


REGISTRY_ALIAS = "champion"
"""Alias that ``commission --register NAME`` moves to the new version."""


class Commissionings:
    """Per-machine bundles, checked against the fleet bundle: a folder or the MLflow registry.

    Parameters
    ----------
    source : str or path
        A folder (``FOLDER/<machine>/``, written by ``hydrowatch commission --out FOLDER/<machine>``),
        or a registry URI template with ``{machine}``, e.g. ``models:/hydrowatch-{machine}@champion``
        (``commission --register hydrowatch-<machine>``).
    fleet : ModelBundle
        The fleet bundle the scorer runs; a commissioning of another fleet version is not used.
    tracking_uri : str, optional
        MLflow tracking URI for a registry template (default as ``train``).
    """

    def __init__(self, source: str | Path, fleet: ModelBundle, tracking_uri: str | None = None) -> None:
        self.source = str(source)
        self.fleet = fleet
        self.tracking_uri = tracking_uri
        self._cache: dict[str, ModelBundle | None] = {}
        if self.source.startswith("models:/") and "{machine}" not in self.source:
            raise DataError(f"--commissioning must be a folder or a registry URI with {{machine}}, e.g. "
                            f"models:/hydrowatch-{{machine}}@champion. Got {self.source!r}.")

    def _load(self, machine: str) -> ModelBundle | None:
        """The machine's bundle as stored, or None (logged) when there is none or it cannot be read."""
        if self.source.startswith("models:/"):
            where = self.source.replace("{machine}", machine)
        else:
            where = str(Path(self.source) / machine)
            if not (Path(where) / MANIFEST).is_file():
                event(_log, "no commissioning for machine, using the fleet model", machine=machine, source=where)
                return None
        try:
            return load_bundle(where, self.tracking_uri)
        except Exception as exc:  # a missing or broken one must not stop the scorer: fall back and say why
            event(_log, "no usable commissioning for machine, using the fleet model", machine=machine, source=where,
                  error=str(exc)[:200])
            return None

    def for_machine(self, machine: str) -> ModelBundle | None:
        """The machine's commissioned bundle, or None (logged once) when it has none usable."""
        if machine in self._cache:
            return self._cache[machine]
        found: ModelBundle | None = None
        bundle = self._load(machine)
        if bundle is not None:
            base = bundle.manifest.get("commissioned", {}).get("base_version")
            if base != self.fleet.version:
                event(_log, "commissioning is of another fleet model version, using the fleet model",
                      machine=machine, commissioned_from=base, fleet=self.fleet.version)
            else:
                found = bundle
        self._cache[machine] = found
        return found

    def forget(self) -> None:
        """Drop what was read (after a fleet model switch or a new commissioning)."""
        self._cache.clear()
