"""Health methods, one package each, registered by name (docs/architecture.md, "Where a new … goes").

:data:`REGISTRY` maps a method's name (``--method NAME``, a manifest's ``method``) to its class, a
subclass of :class:`hydrowatch.methods.base.HealthMethod`; the class is imported on first use
(:func:`method_class`), so the command line lists the methods without loading any model code.
A new method is a package here plus one line in :data:`REGISTRY`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from hydrowatch.errors import DataError

if TYPE_CHECKING:
    from hydrowatch.methods.base import HealthMethod

REGISTRY: dict[str, str] = {
    "parity": "hydrowatch.methods.parity:ParityMethod",
    "entropy": "hydrowatch.methods.entropy:EntropyMethod",
    "stats": "hydrowatch.methods.stats:StatsMethod",
    "cycles": "hydrowatch.methods.cycles:CyclesMethod",
}
"""Method name → ``module:Class``. The first is the default method."""


def method_names() -> tuple[str, ...]:
    """The registered methods, the default first."""
    return tuple(REGISTRY)


def method_class(name: str) -> type[HealthMethod]:
    """The class of the method registered as ``name``.

    Raises
    ------
    DataError
        When no method has that name (a bundle written by a newer hydrowatch, or a typo).
    """
    if name not in REGISTRY:
        raise DataError(f"method must be one of {method_names()}. Got {name!r}: a bundle of a newer hydrowatch? "
                        "Upgrade hydrowatch, or retrain with `hydrowatch train`.")
    module, _, attribute = REGISTRY[name].partition(":")
    cls: type[HealthMethod] = getattr(importlib.import_module(module), attribute)
    return cls
