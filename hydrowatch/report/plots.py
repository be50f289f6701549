"""Report plots as PNG bytes (matplotlib, Agg backend: no display needed).

Each function draws one figure of the study's kind: the confusion matrix (Figures 6.10, 6.11; true
state on rows here), the base prediction-error distributions of one sensor over the health states
(Figures 6.1-6.3), residual correlations (Eqs. 4.22, 4.23), pole-zero maps (section 3.2.3) and
per-machine verdict timelines.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402


def _png(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def confusion_png(matrix: np.ndarray | Sequence[Sequence[int]], labels: Sequence[str], title: str) -> bytes:
    """Confusion matrix, counts, true state on rows and predicted state on columns."""
    m = np.asarray(matrix)
    fig, ax = plt.subplots(figsize=(1.0 + 0.7 * m.shape[1], 0.8 + 0.6 * m.shape[0]))
    ax.imshow(m, cmap="Blues")
    for (i, j), value in np.ndenumerate(m):
        ax.text(j, i, str(int(value)), ha="center", va="center",
                color="white" if value > 0.5 * max(m.max(), 1) else "black", fontsize=8)
    ax.set_xticks(range(m.shape[1]), [str(c) for c in labels][: m.shape[1]], rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(m.shape[0]), [str(c) for c in labels][: m.shape[0]], fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=10)
    return _png(fig)


def error_distributions_png(errors: Mapping[str, np.ndarray], sensor: str, unit: str) -> bytes:
    """Histogram and fitted Gaussian of one sensor's prediction errors, one curve per health state.

    Parameters
    ----------
    errors : mapping of state to ndarray, shape (n,)
        Prediction errors of the sensor on each state's base part, sensor unit.
    """
    fig, ax = plt.subplots(figsize=(7, 3.5))
    every = np.concatenate([np.asarray(e) for e in errors.values()])
    lo, hi = np.quantile(every, [0.002, 0.998])
    grid = np.linspace(lo, hi, 400)
    for state, e in errors.items():
        mu, sd = float(np.mean(e)), float(np.std(e)) or 1e-12
        line = ax.plot(grid, np.exp(-0.5 * ((grid - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), label=state)[0]
        ax.hist(e, bins=80, range=(lo, hi), density=True, alpha=0.15, color=line.get_color())
    ax.set_xlabel(f"{sensor} prediction error [{unit}]")
    ax.set_ylabel("density")
    ax.set_title(f"Base prediction-error distributions: {sensor}", fontsize=10)
    ax.legend(fontsize=7)
    return _png(fig)


def correlations_png(correlations: Mapping[str, Mapping[str, Any]]) -> bytes:
    """Residual autocorrelation and input cross-correlation of each sensor with the white-noise bound."""
    fig, axes = plt.subplots(2, len(correlations), figsize=(3.2 * len(correlations), 4.5), squeeze=False)
    for j, (sensor, c) in enumerate(correlations.items()):
        acf, ccf, bound = np.asarray(c["acf"]), np.asarray(c["ccf"]), float(c["bound"])
        lags = (ccf.size - 1) // 2
        for ax, x, y, name in ((axes[0, j], np.arange(acf.size), acf, "autocorrelation"),
                               (axes[1, j], np.arange(-lags, lags + 1), ccf, "voltage cross-corr.")):
            ax.stem(x, y, basefmt=" ")
            ax.axhline(bound, color="r", ls="--", lw=0.8)
            ax.axhline(-bound, color="r", ls="--", lw=0.8)
            ax.set_title(f"{sensor}: {name}", fontsize=9)
            ax.set_xlabel("lag [samples]", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def pole_zero_png(roots: Mapping[str, Mapping[str, Sequence[Sequence[float]]]]) -> bytes:
    """Poles (x) and zeros (o) of G = B/F and H = C/D of each sensor's Box-Jenkins model, z-plane."""
    fig, axes = plt.subplots(1, len(roots), figsize=(3.2 * len(roots), 3.3), squeeze=False)
    circle = np.exp(1j * np.linspace(0, 2 * np.pi, 200))
    for ax, (sensor, r) in zip(axes[0], roots.items()):
        ax.plot(circle.real, circle.imag, "k", lw=0.6)
        for name, marker, color in (("zeros_B", "o", "C0"), ("poles_F", "x", "C0"),
                                    ("zeros_C", "o", "C1"), ("poles_D", "x", "C1")):
            pts = np.asarray(r.get(name, []), dtype=float).reshape(-1, 2)
            if pts.size and marker == "o":
                ax.scatter(pts[:, 0], pts[:, 1], marker=marker, facecolors="none", edgecolors=color, label=name)
            elif pts.size:
                ax.scatter(pts[:, 0], pts[:, 1], marker=marker, c=color, label=name)
        ax.set_aspect("equal")
        ax.set_title(f"{sensor} (G blue, H orange)", fontsize=9)
        ax.legend(fontsize=6)
    return _png(fig)


def timeline_png(timelines: Mapping[str, Sequence[tuple[float, float, str]]], states: Sequence[str]) -> bytes:
    """Verdict of every machine over time: one row per machine, one colour per state.

    Parameters
    ----------
    timelines : mapping of machine to sequence of (window start [s], window end [s], state)
    states : sequence of str
        Colour order; ``unknown`` and ``invalid`` are added.
    """
    labels = [*states, "unknown", "invalid"]
    colours = {s: plt.get_cmap("tab10")(i % 10) for i, s in enumerate(labels)}
    colours["invalid"] = (0.6, 0.6, 0.6, 1.0)
    fig, ax = plt.subplots(figsize=(9, 0.5 + 0.35 * max(1, len(timelines))))
    for row, points in enumerate(timelines.values()):
        for start, end, state in points:
            ax.barh(row, end - start, left=start, color=colours.get(state, "k"), height=0.8)
    ax.set_yticks(range(len(timelines)), list(timelines), fontsize=7)
    ax.set_xlabel("time [s]")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[s]) for s in labels]
    ax.legend(handles, labels, fontsize=6, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_title("Verdicts per machine", fontsize=10)
    return _png(fig)
