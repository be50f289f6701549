"""Where a simulation error lives: per sensor, per operating regime, per frequency band, in time.

Pure array statistics on a residual ``e = measured − simulated`` (gap-method.md, step 3): the
fit per channel (NRMSE, fit %), the sensor noise floor, binned mean and RMS with standard errors by
command level, speed, torque (a load-pressure proxy, Eq. 7: Dm·PL ≈ torque/(N·η)), direction of
command change, acceleration and time, the share of the residual energy in frequency bands, the
coherence with the command and the residual–command cross-correlation peak lag.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from hydrowatch.recording import SAMPLE_RATE_HZ

FREQUENCY_BANDS_HZ: tuple[tuple[float, float], ...] = ((0.0, 0.2), (0.2, 2.0), (2.0, 10.0), (10.0, 40.0), (40.0, 100.0))
"""Bands (Hz) in which the residual energy is split; the first is the time-drift band."""

NOISE_BAND_HZ = (70.0, 100.0)
"""Band where the plant's response has died out and the residual spectrum is the sensor noise, Hz."""


def nrmse(measured: np.ndarray, simulated: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Normalised root-mean-square error RMS(y − ŷ) / std(y) (contract: ``fit`` of ``hydrowatch gap``).

    Parameters
    ----------
    measured, simulated : ndarray, shape (n,)
        One channel, any unit.
    mask : ndarray of bool, shape (n,), optional
        Samples to use (held-out data); all when None.
    """
    y, yhat = (measured, simulated) if mask is None else (measured[mask], simulated[mask])
    scale = float(np.std(y))
    return float(np.sqrt(np.mean((y - yhat) ** 2)) / scale) if scale > 0 else float("nan")


def fit_percent(measured: np.ndarray, simulated: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Fit % = 100·(1 − ‖y − ŷ‖/‖y − ȳ‖), the system-identification goodness of fit."""
    return 100.0 * (1.0 - nrmse(measured, simulated, mask))


def noise_std(residual: np.ndarray, fs: float = SAMPLE_RATE_HZ) -> float:
    """Standard deviation of the white sensor noise in a residual, from its spectrum in NOISE_BAND_HZ.

    A white noise of variance σ² has a one-sided density 2σ²/fs; the median of the density in the
    band is robust to the narrow lines of pump ripple.
    """
    nper = int(min(512, residual.size))
    f, pxx = signal.welch(residual - residual.mean(), fs=fs, nperseg=nper)
    band = (f >= NOISE_BAND_HZ[0]) & (f <= NOISE_BAND_HZ[1])
    return float(np.sqrt(np.median(pxx[band]) * fs / 2.0))


@dataclass(frozen=True)
class Regime:
    """One region of the operating space.

    Attributes
    ----------
    family : str
        What the region is defined by: ``command``, ``speed``, ``torque``, ``command direction``,
        ``acceleration``, ``time`` or ``frequency``.
    label : str
        Human-readable bounds, e.g. ``"speed < 1.3 rad/s"``.
    share : float
        Share of the sensor's residual energy (above the noise) inside the region, 0…1.
    fraction : float
        Share of the samples (or of the bandwidth's noise energy) inside the region, 0…1.
    mean, rms, mean_se : float
        Residual mean, RMS and the standard error of the mean inside the region, sensor unit.
    """

    family: str
    label: str
    share: float
    fraction: float
    mean: float
    rms: float
    mean_se: float

    @property
    def concentration(self) -> float:
        """How much more of the error the region holds than its size would suggest (share − fraction)."""
        return self.share - self.fraction


def _quantile_bins(x: np.ndarray, n_bins: int) -> np.ndarray:
    edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
    return edges


def _regimes_from_masks(
    family: str, masks: list[tuple[str, np.ndarray]], residual: np.ndarray, noise_var: float
) -> list[Regime]:
    excess = np.maximum(residual**2 - noise_var, 0.0)
    total = float(excess.sum()) or 1.0
    out = []
    for label, mask in masks:
        n = int(mask.sum())
        if n < 10:
            continue
        r = residual[mask]
        out.append(
            Regime(
                family, label, float(excess[mask].sum() / total), n / residual.size, float(r.mean()),
                float(np.sqrt(np.mean(r**2))), float(r.std(ddof=1) / np.sqrt(n)),
            )
        )
    return out


def _binned(
    family: str, unit: str, x: np.ndarray, residual: np.ndarray, noise_var: float, n_bins: int = 5
) -> list[Regime]:
    edges = _quantile_bins(x, n_bins)
    masks = []
    for i in range(len(edges) - 1):
        lo, hi = edges[i], edges[i + 1]
        mask = (x >= lo) & ((x < hi) if i < len(edges) - 2 else (x <= hi))
        masks.append((f"{family} {lo:.3g}…{hi:.3g} {unit}".strip(), mask))
    return _regimes_from_masks(family, masks, residual, noise_var)


def band_shares(residual: np.ndarray, noise_var: float, fs: float = SAMPLE_RATE_HZ) -> list[Regime]:
    """Share of the residual energy above the noise in each of FREQUENCY_BANDS_HZ (Welch spectrum)."""
    nper = int(min(2048, residual.size))
    f, pxx = signal.welch(residual, fs=fs, nperseg=nper, detrend=False)
    df = f[1] - f[0]
    excess = np.maximum(pxx - 2.0 * noise_var / fs, 0.0) * df
    total = float(excess.sum()) or 1.0
    out = []
    for lo, hi in FREQUENCY_BANDS_HZ:
        band = (f >= lo) & (f < hi) if hi < fs / 2 else (f >= lo)
        out.append(
            Regime("frequency", f"{lo:g}–{hi:g} Hz", float(excess[band].sum() / total), (hi - lo) / (fs / 2.0),
                   float("nan"), float(np.sqrt(pxx[band].sum() * df)), float("nan"))
        )
    return out


def regimes(
    residual: np.ndarray, voltage: np.ndarray, speed: np.ndarray, torque: np.ndarray, noise_var: float,
    fs: float = SAMPLE_RATE_HZ,
) -> list[Regime]:
    """Every region of the operating space with the residual's statistics in it.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        Measured minus simulated of one sensor.
    voltage : ndarray, shape (n,)
        Command, V.
    speed, torque : ndarray, shape (n,)
        Gearbox speed [rad/s] and torque [N·m] (simulated: noise-free operating point).
    noise_var : float
        Variance of the sensor noise (``noise_std(residual)**2``), sensor unit squared.
    """
    du = np.gradient(voltage) * fs
    acc = np.gradient(speed) * fs
    thresh = max(float(np.std(du)) * 0.25, 1e-9)
    direction = [
        ("command rising", du > thresh), ("command falling", du < -thresh), ("command steady", np.abs(du) <= thresh),
    ]
    n = residual.size
    thirds = [(f"time {i}/3 of the record", (np.arange(n) >= i * n // 3) & (np.arange(n) < (i + 1) * n // 3))
              for i in range(3)]
    return (
        _binned("command", "V", voltage, residual, noise_var)
        + _binned("speed", "rad/s", speed, residual, noise_var)
        + _binned("torque", "N·m", torque, residual, noise_var)
        + _regimes_from_masks("command direction", direction, residual, noise_var)
        + _binned("acceleration", "rad/s²", acc, residual, noise_var)
        + _regimes_from_masks("time", thirds, residual, noise_var)
        + band_shares(residual, noise_var, fs)
    )


def strongest_regime(found: list[Regime]) -> Regime:
    """The region that holds the most error beyond its size (largest share − fraction)."""
    return max(found, key=lambda r: r.concentration)


def coherence_with_input(residual: np.ndarray, voltage: np.ndarray, fs: float = SAMPLE_RATE_HZ) -> float:
    """Mean magnitude-squared coherence between command and residual below 20 Hz, 0…1.

    Near the bias of the estimator (≈ 1/segments) when the residual is independent of the input.
    """
    nper = int(min(256, residual.size))
    f, cxy = signal.coherence(voltage, residual, fs=fs, nperseg=nper)
    return float(np.mean(cxy[(f > 0) & (f < 20.0)]))


def cross_correlation_peak(residual: np.ndarray, voltage: np.ndarray, max_lag: int = 100) -> tuple[int, float]:
    """Lag (samples, residual after command when positive) and value of the peak normalised correlation."""
    r = (residual - residual.mean()) / (residual.std() or 1.0)
    u = (voltage - voltage.mean()) / (voltage.std() or 1.0)
    n = r.size
    lags = np.arange(-max_lag, max_lag + 1)
    values = np.array([np.dot(r[max(k, 0): n + min(k, 0)], u[max(-k, 0): n - max(k, 0)]) / n for k in lags])
    i = int(np.argmax(np.abs(values)))
    return int(lags[i]), float(values[i])


def whiteness(residual: np.ndarray, max_lag: int = 25) -> float:
    """Ljung–Box-like statistic normalised by its degrees of freedom: ≈ 1 for white noise, ≫ 1 otherwise."""
    r = residual - residual.mean()
    n = r.size
    var = float(np.dot(r, r)) / n or 1.0
    acf = np.array([np.dot(r[k:], r[: n - k]) / (n * var) for k in range(1, max_lag + 1)])
    return float(n * np.sum(acf**2) / max_lag)
