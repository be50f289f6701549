"""A stiff machine is integrated inside RK4's stability region: the kernel shortens its step where the fastest mode
(:func:`fastest_rate`, checked against the Jacobian's eigenvalues) would leave it, and leaves every unit of the
default populations on its fixed step (issue 12, item 5: a calibration visiting a stiff relief ran 20–30× slower on
a ringing trajectory)."""

import numpy as np
import pytest

from hydrowatch.plant import PlantParameters, PlantSimulator
from hydrowatch.plant.dynamics import N_COEF, N_LOAD, N_ODE, PS, TEMP, TH, WM, coefficients, fastest_rate, rates
from hydrowatch.plant.effects import effect_row, resolve_effects
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.kernel import STABLE_STEP
from hydrowatch.plant.population import population
from hydrowatch.plant.simulator import DEFAULT_SUBSTEPS

FS = 200.0
STIFF_RELIEF = {"Kr": 3.0, "Vs": 0.5}
"""Relief gain ×3 and supply volume ×0.5: h·|λ| = 3.7 at the default step (a calibration visited this)."""


def scaled(**factors: float) -> PlantParameters:
    nominal = PlantParameters()
    return nominal.replace(**{name: getattr(nominal, name) * f for name, f in factors.items()})


def coefficient_row(p: PlantParameters) -> np.ndarray:
    c = np.empty(N_COEF + N_LOAD)
    coefficients(p.as_array(), c)
    return c


def jacobian_radius(p: PlantParameters, effects: dict | None, y: np.ndarray) -> float:
    """Largest |eigenvalue| of d(rates)/d(state) at y by central differences, 1/s."""
    c, e = coefficient_row(p), effect_row(resolve_effects(effects))
    ds, sensors, jac = np.empty(N_ODE), np.empty(3), np.zeros((N_ODE, N_ODE))
    for i in range(N_ODE):
        step = 1e-6 * max(abs(y[i]), 1.0)
        hi, lo = y.copy(), y.copy()
        hi[i] += step
        lo[i] -= step
        rates(c, e, hi, 0.0, 0.0, False, ds, sensors)
        up = ds.copy()
        rates(c, e, lo, 0.0, 0.0, False, ds, sensors)
        jac[:, i] = (up - ds) / (2.0 * step)
    return float(np.max(np.abs(np.linalg.eigvals(jac))))


def relief_open_state(p: PlantParameters) -> np.ndarray:
    """Spool closed (the valve's state-dependent conductance is zero), supply 1 bar above cracking, motor turning,
    a flexible driveline twisted 10 mrad (teeth in full contact: past the contact damping's 1 mrad ramp)."""
    y = np.zeros(N_ODE)
    y[PS] = p.Pc + 1e5
    y[WM] = 20.0
    y[TH] = 0.01
    y[TEMP] = 40.0
    return y


@pytest.mark.parametrize(
    ("factors", "effects", "dominant"),
    [
        ({}, None, False),
        (STIFF_RELIEF, None, True),
        ({}, {"shaft_compliance": {"G": 10000.0, "c": 10.0}}, False),
        ({"Jm": 0.4}, {"gear_backlash": {"b": 0.0, "K": 10000.0, "c": 0.5}}, False),
    ],
)
def test_the_fastest_rate_bounds_the_jacobians_eigenvalues(factors: dict, effects: dict | None,
                                                           dominant: bool) -> None:
    p = scaled(**factors)
    rate = fastest_rate(coefficient_row(p), effect_row(resolve_effects(effects)))
    radius = jacobian_radius(p, effects, relief_open_state(p))
    assert radius <= 1.01 * rate
    assert radius >= 0.3 * rate  # a bound, not a guess: within ×3.3 of the truth
    if dominant:  # the relief's mode is the fastest and the bound is its exact rate
        assert radius == pytest.approx(rate, rel=0.01)


def test_every_unit_of_the_default_populations_keeps_the_fixed_step() -> None:
    """Units ±30 % in every parameter (as the gap benchmark draws them) and :func:`random_unit`'s defaults (±20 %,
    leakages and damping ±50 %) stay well inside the region, so their simulations are the fixed-step ones bit for
    bit."""
    h = 1.0 / (FS * DEFAULT_SUBSTEPS)
    e = effect_row(resolve_effects(None))
    worst = 0.0
    for kwargs in ({"spread": 0.3, "wide_spread": 0.3}, {}):
        for unit in population(200, 11, **kwargs):
            worst = max(worst, h * fastest_rate(coefficient_row(unit), e))
    assert worst < 0.8 * STABLE_STEP


def test_a_stiff_relief_simulates_as_with_eight_times_the_substeps() -> None:
    """At the default step the stiff relief would ring (RK4 unstable, h·|λ| 3.7): the shortened step matches a run at
    8× the substeps to a tenth of each sensor's noise (measured: rms 3 % of it), and its supply pressure settles."""
    p = scaled(**STIFF_RELIEF)
    u = filtered_noise(20.0, (-4.0, 4.0), seed=5)
    runs = [PlantSimulator(p, noise=False, substeps=s).step(u) for s in (DEFAULT_SUBSTEPS, 8 * DEFAULT_SUBSTEPS)]
    for sensor, sd in (("flow", p.noise_flow), ("speed", p.noise_speed), ("torque", p.noise_torque)):
        rms = float(np.sqrt(np.mean((runs[0][sensor] - runs[1][sensor]) ** 2)))
        assert rms < 0.1 * sd, sensor
    still = PlantSimulator(p, noise=False)
    still.settle(0.0)
    supply = still.step(np.zeros(200))["supply_pressure"]
    assert np.ptp(supply) < 1e-6  # bar: no limit cycle at the relief's cracking pressure
