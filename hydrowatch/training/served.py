"""Which rig a scorer serves, and the refusal of a model made for another (issue 17, docs/rigs.md).

A bundle is made for one rig: a ``cycles`` bundle for the rig of the description it keeps (``cycles/rig.toml``),
a bundle of any other method for the plant (:func:`~hydrowatch.rig.plant.plant_rig`). A scorer serves one rig: the
one named by its ``--rig``, else the rig of the first model it loads. A model whose rig has another name, or that
reads a channel the served rig does not have, is refused with :func:`check_served`: loaded at start, the scorer
stops with the error; met on a followed alias, the scorer keeps the model in use and logs it (services/scorer).
"""

from __future__ import annotations

from hydrowatch.errors import DataError
from hydrowatch.rig import RigDescription
from hydrowatch.rig.plant import plant_rig
from hydrowatch.training.bundle import ModelBundle


def bundle_rig(bundle: ModelBundle) -> RigDescription:
    """The rig ``bundle`` was trained for: a cycles bundle's description, else the plant's."""
    rig = getattr(bundle.health_method, "rig", None)
    return rig if isinstance(rig, RigDescription) else plant_rig()


def rig_differences(bundle: ModelBundle, served: RigDescription) -> list[str]:
    """What keeps ``bundle`` from serving ``served``, in words (empty when it can): another rig name; channels it
    reads that ``served`` lacks."""
    rig, method = bundle_rig(bundle), bundle.health_method
    found: list[str] = []
    if rig.name != served.name:
        found.append(f"its rig is {rig.name!r}, not {served.name!r}")
    missing = [c for c in method.channels if c not in served.channels.names]
    if missing:
        found.append(f"it reads channels {missing} that {served.name!r} does not have ({list(served.channels.names)})")
    return found


def check_served(bundle: ModelBundle, served: RigDescription, model: str) -> None:
    """Refuse ``bundle`` (loaded from ``model``, a folder or registry URI) when it cannot serve ``served``.

    Raises
    ------
    DataError
        Naming the model, its version and method, the served rig, and each difference (:func:`rig_differences`).
    """
    differences = rig_differences(bundle, served)
    if differences:
        raise DataError(
            f"the model must be made for rig {served.name!r}, which this scorer serves. Got {bundle.method} bundle "
            f"{bundle.version} of rig {bundle_rig(bundle).name!r}: {'; '.join(differences)}. Give the scorer the "
            f"rig's own model (--model; a rig's registered name is hydrowatch-<rig>) or the --rig it was made for.",
            model)
