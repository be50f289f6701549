"""Populations of simulated units: machines whose every parameter differs from the defaults, and their later days.

A figure counts only when measured on units that did not tune it. :func:`random_unit` draws one
physical unit of the transmission (every nominal parameter of plant-model.md's table moved, a
DAQ with its own noise levels); :func:`later_day` the same unit on a later day (leakages, load and
damping drifted a few percent, as oil, seals and bearings change between days). Both are plain
functions of a ``numpy.random.Generator``, so a population is reproducible from one seed
(:func:`population`).

What is not drawn, and why: ``N`` (the gearbox ratio is a known integer ratio), ``u_max`` (the
command scale is a datasheet value the DAQ is set up for), ``Kc`` (a scale factor that only
multiplies ``Kq``: drawing both would double one effect), ``Cvx`` and ``Cpl`` (0 on a healthy
unit: they are the fault parameters of valve_leak and pump_leak), and ``eta`` is kept ≤ 1.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import ParameterError
from hydrowatch.plant.parameters import PlantParameters

UNIT_PARAMETERS: tuple[str, ...] = (
    "Dp", "omega_p", "Pc", "Kr", "Vs", "beta_e", "Kq", "omega_v", "zeta_v", "Vt", "Dm", "Jm", "N_eta",
    "JL", "TL", "omega_s",
)
"""Parameters drawn within ±``spread`` (``N_eta`` stands for the gearbox efficiency, drawn below 1)."""
WIDE_PARAMETERS: tuple[str, ...] = ("Cp", "Cvl", "Ctm", "Bm", "BL")
"""Leakages and damping: drawn within ±``wide_spread`` (they vary most between units)."""
DRIFT_PARAMETERS: tuple[str, ...] = ("Cp", "Cvl", "Ctm", "Bm", "BL", "TL")
"""What moves between days of one unit: leakages (seals, oil), damping (bearings, oil), the load's brake torque."""
NOISE_CHANNELS: tuple[str, ...] = tuple(f"noise_{s}" for s in PLANT.sensors)
"""Sensor-noise parameters, one per health sensor in kernel column order."""


def _check_fraction(name: str, value: float, upper: float = 0.9) -> float:
    v = float(value)
    if not (np.isfinite(v) and 0.0 <= v < upper):
        raise ParameterError(f"{name} must be a fraction in [0, {upper}). Got {value!r}; e.g. 0.2 for ±20 %.")
    return v


def random_unit(rng: np.random.Generator, *, spread: float = 0.2, wide_spread: float = 0.5,
                noise: tuple[float, float] = (1.0, 3.0), nominal: PlantParameters | None = None) -> PlantParameters:
    """One physical unit: each parameter of :data:`UNIT_PARAMETERS` × U(1 ± spread), of
    :data:`WIDE_PARAMETERS` × U(1 ± wide_spread), and each sensor's noise σ × U(noise) of the default.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    spread : float, default 0.2
        Relative half-width for most parameters.
    wide_spread : float, default 0.5
        Relative half-width for leakages and damping.
    noise : (float, float), default (1, 3)
        Range of the factor on each sensor's noise standard deviation (1: the default DAQ).
    nominal : PlantParameters, optional
        The design values (default: plant-model.md's table).
    """
    s, w = _check_fraction("spread", spread), _check_fraction("wide_spread", wide_spread)
    lo, hi = (float(v) for v in noise)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi):
        raise ParameterError(f"noise must be a range (low, high) of factors with 0 <= low <= high. Got {noise!r}.")
    p = nominal if nominal is not None else PlantParameters()
    changes: dict[str, float] = {}
    for name in UNIT_PARAMETERS:
        if name == "N_eta":  # efficiency: the loss 1 − η scaled, so η stays below 1
            changes["eta"] = 1.0 - (1.0 - p.eta) * float(rng.uniform(1.0 - s, 1.0 + s))
        else:
            changes[name] = getattr(p, name) * float(rng.uniform(1.0 - s, 1.0 + s))
    for name in WIDE_PARAMETERS:
        changes[name] = getattr(p, name) * float(rng.uniform(1.0 - w, 1.0 + w))
    for name in NOISE_CHANNELS:
        changes[name] = getattr(p, name) * float(rng.uniform(lo, hi))
    return p.replace(**changes)


def later_day(unit: PlantParameters, rng: np.random.Generator, *, drift: tuple[float, float] = (0.03, 0.05)
              ) -> PlantParameters:
    """The same unit on a later day: each of :data:`DRIFT_PARAMETERS` moved by ±U(drift) (a random sign each).

    Parameters
    ----------
    unit : PlantParameters
        The unit as identified (its training day).
    rng : numpy.random.Generator
        Source of the draws.
    drift : (float, float), default (0.03, 0.05)
        Range of the relative change's magnitude.
    """
    lo, hi = (_check_fraction("drift", v) for v in drift)
    if lo > hi:
        raise ParameterError(f"drift must be a range (low, high) with low <= high. Got {drift!r}.")
    changes = {}
    for name in DRIFT_PARAMETERS:
        sign = 1.0 if rng.random() < 0.5 else -1.0
        changes[name] = getattr(unit, name) * (1.0 + sign * float(rng.uniform(lo, hi)))
    return unit.replace(**changes)


def population(n_units: int, seed: int, **kwargs: float | tuple[float, float]) -> Iterator[PlantParameters]:
    """``n_units`` units from :func:`random_unit`, one generator seeded by ``seed`` (keyword arguments passed on)."""
    if int(n_units) != n_units or n_units < 1:
        raise ParameterError(f"n_units must be an integer >= 1. Got {n_units!r}.")
    rng = np.random.default_rng(seed)
    for _ in range(int(n_units)):
        yield random_unit(rng, **kwargs)  # type: ignore[arg-type]
