"""The space a grey-box calibration searches: which plant parameters and effect parameters move, from where,
within which bounds, under which design-value prior (:class:`ModelSpace`; :mod:`hydrowatch.gap.calibrate` fits in it).

Plant parameters are log-scale factors of their starting value; effect parameters multiples of their catalog
default (gap-method.md, step 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hydrowatch.plant.effects import EFFECTS
from hydrowatch.plant.parameters import PlantParameters

CALIBRATED: tuple[str, ...] = ("Kq", "TL", "BL", "JL", "Ctm", "beta_e", "omega_v", "Cp", "Pc", "Dp", "Dm", "Kr",
                                "Vs", "Vt", "Cvl", "zeta_v", "Jm", "Bm")
"""Plant parameters a unit's calibration estimates before any effect is blamed: every coefficient
of plant-model.md's table that differs between units (not the gearbox ratio N, the pump shaft speed
ωp, the command scale u_max, the coil gain Kc that only multiplies Kq, the brake's smoothing speed
ωs, the gearbox efficiency η, nor the fault parameters Cvx and Cpl). Which of them (or which
combinations) a recording determines is decided from its Fisher information (identify.py)."""

PRIOR_SD = math.log(1.5)
"""Standard deviation of the design-value prior on each calibrated parameter's log (a unit is
within a factor 1.5 of its design values at one σ). It only holds what the recording does not
determine (Cp against Cvl: both are leaks supply → tank) near the design value."""

SCALE_BOUND = 3.0
"""Plant parameters may move by a factor 1/SCALE_BOUND … SCALE_BOUND from their design value (a space
with a prior) or else from their starting value. Design-relative since issue 12's third pass: a
hypothesis's fit that starts from an already moved model could reach a relief gain Kr ×5.6 with a
spool ×3.5 faster (population 2034), where each simulation took 1.4 s instead of 0.07 s (RK4 steps
split at the relief valve's kink every step). That slowness had a cause of its own, mended in the kernel since: the
fixed step was outside RK4's stability region for so stiff a relief (``plant.kernel.STABLE_STEP``)."""


@dataclass(frozen=True)
class ModelSpace:
    """Which numbers of a model (plant parameters + effects) are free, and their scaled coordinates.

    Attributes
    ----------
    base : PlantParameters
        Starting (and fixed) plant parameters.
    effects : dict
        Effects switched on, ``{id: {param: value}}`` (fixed values and starting values).
    plant_free : tuple of str
        Plant parameters to estimate; coordinate = ln(value / base value).
    effect_free : tuple of (str, str)
        ``(effect id, parameter)`` pairs to estimate; coordinate = value / catalog default.
    prior : PlantParameters, optional
        Design values: each free plant parameter then adds the residual
        ``prior_weight · ln(value / design value) / PRIOR_SD`` to the cost (a Gaussian prior on its
        log, MAP estimation). None: plain least squares.
    prior_weight : float
        The noise level in normalised units (the RMS noise ceiling) that puts the prior on the
        scale of the normalised errors, dimensionless.
    """

    base: PlantParameters
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    plant_free: tuple[str, ...] = CALIBRATED
    effect_free: tuple[tuple[str, str], ...] = ()
    prior: PlantParameters | None = None
    prior_weight: float = 0.0

    def prior_residuals(self, z: np.ndarray) -> np.ndarray:
        """The prior's residuals at coordinates ``z``, shape (len(plant_free),) or (0,) without a prior."""
        if self.prior is None:
            return np.zeros(0)
        offset = np.array([math.log(getattr(self.base, n) / getattr(self.prior, n)) for n in self.plant_free])
        return self.prior_weight * (z[: len(self.plant_free)] + offset) / PRIOR_SD

    @property
    def names(self) -> list[str]:
        """Coordinate names: plant names, then ``id.param``."""
        return [*self.plant_free, *(f"{e}.{p}" for e, p in self.effect_free)]

    def start(self) -> np.ndarray:
        """Scaled coordinates of the starting model, shape (P,)."""
        eff = [self.effects[e][p] / EFFECTS[e].parameters[p][0] for e, p in self.effect_free]
        return np.array([0.0] * len(self.plant_free) + eff)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the scaled coordinates, shape (P,) each: a plant parameter within a
        factor SCALE_BOUND of the design value when the space has a prior, else of its starting value."""
        centre = [0.0] * len(self.plant_free) if self.prior is None else [
            math.log(getattr(self.prior, n) / getattr(self.base, n)) for n in self.plant_free]
        lo = [c - math.log(SCALE_BOUND) for c in centre]
        hi = [c + math.log(SCALE_BOUND) for c in centre]
        for e, p in self.effect_free:
            default, _, _, lower, upper = EFFECTS[e].parameters[p]
            lo.append(lower / default)
            hi.append(upper / default)
        return np.array(lo), np.array(hi)

    def model(self, z: np.ndarray) -> tuple[PlantParameters, dict[str, dict[str, float]]]:
        """Plant parameters and effects at scaled coordinates ``z``."""
        k = len(self.plant_free)
        params = self.base.replace(**{n: getattr(self.base, n) * math.exp(v) for n, v in zip(self.plant_free, z[:k])})
        effects = {e: dict(v) for e, v in self.effects.items()}
        for (e, p), v in zip(self.effect_free, z[k:]):
            default, _, _, lower, upper = EFFECTS[e].parameters[p]
            effects[e][p] = float(min(max(v * default, lower), upper))
        friction = effects.get("stribeck_friction")
        if friction is not None:
            friction["Ts"] = max(friction["Ts"], friction["Tc"])
        return params, effects

    def values(self, z: np.ndarray) -> dict[str, float]:
        """Physical value of every free coordinate, ``{name: value}`` (SI / catalog units)."""
        params, effects = self.model(z)
        out = {n: getattr(params, n) for n in self.plant_free}
        out.update({f"{e}.{p}": effects[e][p] for e, p in self.effect_free})
        return out
