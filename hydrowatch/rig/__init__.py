"""Rig descriptions: any hydraulic rig's channels, windows and labels (docs/rigs.md).

:func:`load_rig` reads a TOML description, :func:`builtin_rig` one shipped here
(``uci-hydraulic``); :func:`hydrowatch.rig.plant.plant_rig` is the project's own plant (kept
in its own module: it imports the plant's health states).
"""

from hydrowatch.rig.description import (
    BUILTIN,
    DATA_ENV,
    LAYOUTS,
    WINDOW_KINDS,
    Label,
    RigDescription,
    Sampling,
    Window,
    builtin_rig,
    data_root,
    load_rig,
    parse_rig,
)

__all__ = [
    "BUILTIN",
    "DATA_ENV",
    "LAYOUTS",
    "WINDOW_KINDS",
    "Label",
    "RigDescription",
    "Sampling",
    "Window",
    "builtin_rig",
    "data_root",
    "load_rig",
    "parse_rig",
]
