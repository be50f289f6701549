"""The project's own plant as a rig description, built from :data:`hydrowatch.channels.PLANT`.

The channels (names, units, roles, which are optional) are read from the channel registry, the
sample rate from :data:`hydrowatch.recording.SAMPLE_RATE_HZ` and the health states from
:data:`hydrowatch.plant.faults.EXTENDED_STATES`, so each fact stays in one place. It is the
default description: what ``hydrowatch import/train/score`` assume when no rig is named.
"""

from __future__ import annotations

from hydrowatch.channels import LABEL, PLANT, TIME
from hydrowatch.errors import DataError
from hydrowatch.plant.faults import EXTENDED_STATES, HEALTHY
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.rig.description import BUILTIN, Label, RigDescription, Sampling, Window, builtin_rig, load_rig

PLANT_RIG = "plant"
"""Name of the plant's description (``--rig plant``; the rig of every bundle of a method other than ``cycles``)."""

WINDOW_S = 5.0
"""Window of the plant, s: 1000 samples at 200 Hz, the classifier window of
:class:`hydrowatch.health.plan.DataPlan` (windows do not overlap by default)."""


def plant_rig() -> RigDescription:
    """The simulated servo-valve hydrostatic transmission (contract.md, "Data files") as a description.

    Long layout (CSV/Parquet/MCAP: a time column ``t`` and one column per channel at 200 Hz),
    fixed windows of :data:`WINDOW_S` without overlap, one label ``state`` per row or per file
    (``healthy`` or ``<fault>_<warning|alert>``).
    """
    return RigDescription(
        name=PLANT_RIG,
        channels=PLANT,
        sampling={c.name: Sampling(SAMPLE_RATE_HZ, c.name) for c in PLANT},
        window=Window("fixed", WINDOW_S, WINDOW_S, SAMPLE_RATE_HZ),
        layout="long",
        labels=(Label(LABEL, None, EXTENDED_STATES, HEALTHY),),
        time_column=TIME,
        description="simulated servo-valve controlled hydrostatic transmission (hydrowatch's own plant)",
    )


def any_rig(rig: str) -> RigDescription:
    """The description named on a command line: ``plant`` (:func:`plant_rig`), a shipped name or a .toml path.

    Raises
    ------
    DataError
        Naming what is accepted, for anything else; as :func:`~hydrowatch.rig.load_rig` for a bad file.
    """
    if rig == PLANT_RIG:
        return plant_rig()
    if rig in BUILTIN:
        return builtin_rig(rig)
    if not rig.endswith(".toml"):
        raise DataError(f"rig must be a .toml file, {PLANT_RIG!r} or one of {list(BUILTIN)}. Got {rig!r}.")
    return load_rig(rig)
