"""The discovery test: is a model's held-out error beyond what sensor noise and parameter uncertainty explain?

For each sensor the statistic is the held-out mean square of the simulation error over the sensor
noise variance read from the same residual's 70–100 Hz band (locate.noise_std):

    T = mean(e²; held-out) / σ̂²,   σ̂ = noise_std(e; every sample after the burn-in).

Under the null hypothesis (the model's structure is right, its parameters are the calibrated
estimates) the error is white sensor noise plus the estimation error's image J·δθ, whose expected
held-out mean square is σ²·P/n_fit for P estimated coordinates on n_fit fitting samples. The noise
part of T's null distribution (both its numerator and the band estimate σ̂ fluctuate) is drawn by
Monte Carlo on white Gaussian noise of the record's length and held-out layout (NULL_DRAWS
draws, seeded: the same record always gets the same threshold); the threshold is its mean plus
z·sd, z the normal quantile of 1 − FALSE_ALARM / 3 (Bonferroni over the three sensors), plus P/n_fit.
A model **fails** the test when some sensor's T exceeds its threshold: only then is missing physics
looked for (catalog effects, then ``unidentified``), and only sensors that still fail after the
accepted effects may get an ``unidentified`` correction.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.stats import norm

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.locate import noise_std
from hydrowatch.recording import SENSORS

FALSE_ALARM = 0.01
"""Probability that a model with the right structure fails the test on some sensor (family-wise)."""

NULL_DRAWS = 200
"""Monte Carlo draws of white noise that give the null mean and spread of T."""


@dataclass(frozen=True)
class ResidualTest:
    """Outcome of :func:`residual_test`.

    Attributes
    ----------
    statistic : dict of str to float
        T per sensor (held-out mean square error / noise variance), dimensionless.
    threshold : dict of str to float
        The level T must exceed to fail, per sensor.
    beyond : tuple of str
        Sensors whose T exceeds its threshold (empty: the model explains the record).
    """

    statistic: dict[str, float]
    threshold: dict[str, float]
    beyond: tuple[str, ...]

    @property
    def fails(self) -> bool:
        """Whether some sensor's error is beyond noise and parameter uncertainty."""
        return bool(self.beyond)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form (the report's ``discovery_test``)."""
        return {"statistic": {k: round(v, 4) for k, v in self.statistic.items()},
                "threshold": {k: round(v, 4) for k, v in self.threshold.items()},
                "beyond": list(self.beyond), "false_alarm": FALSE_ALARM}


def residual_test(aligned: AlignedRecording, prediction: np.ndarray, n_parameters: int) -> ResidualTest:
    """The discovery test of one model's prediction (module docstring).

    Parameters
    ----------
    aligned : AlignedRecording
    prediction : ndarray, shape (3, n)
        Noise-free simulation of the model, sensor units.
    n_parameters : int
        Coordinates the model's fit estimated (P).
    """
    used = aligned.used_mask
    held = aligned.holdout_mask[used]
    mean, sd = _null_moments(np.packbits(held).tobytes(), int(held.size))
    z = float(norm.ppf(1.0 - FALSE_ALARM / len(SENSORS)))
    level = mean + z * sd + n_parameters / max(int(aligned.fit_mask.sum()), 1)
    statistic, threshold, beyond = {}, {}, []
    for i, sensor in enumerate(SENSORS):
        e = aligned.measured[i, used] - prediction[i, used]
        t = float(np.mean(e[held] ** 2) / max(noise_std(e) ** 2, 1e-300))
        statistic[sensor], threshold[sensor] = t, level
        if t > level:
            beyond.append(sensor)
    return ResidualTest(statistic, threshold, tuple(beyond))


@lru_cache(maxsize=16)
def _null_moments(packed_mask: bytes, n: int) -> tuple[float, float]:
    """Mean and standard deviation of T on white noise of n samples with this held-out mask (packed bits)."""
    held = np.unpackbits(np.frombuffer(packed_mask, dtype=np.uint8))[:n].astype(bool)
    rng = np.random.default_rng(20261125)
    draws = []
    for _ in range(NULL_DRAWS):
        e = rng.standard_normal(n)
        draws.append(float(np.mean(e[held] ** 2) / noise_std(e) ** 2))
    return float(np.mean(draws)), float(np.std(draws, ddof=1))
