"""The HTML report of ``hydrowatch gap``: summary, tables and plots (PNG embedded as base64).

Plots: fit per sensor (nominal, calibrated, final NRMSE next to the noise ceiling), overlays of
measured and simulated sensors on a held-out stretch, residual spectra before and after, and the
residual's autocorrelation and cross-correlation with the command.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import signal

from hydrowatch.recording import SAMPLE_RATE_HZ, SENSORS, UNITS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from hydrowatch.gap.analysis import GapAnalyser

OVERLAY_SECONDS = 2.5
"""Length of the held-out stretch shown in the overlays (within one held-out block), s."""


def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _fit_bars(report: dict) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3))
    x = np.arange(len(SENSORS))
    for k, name in enumerate(("nominal", "calibrated", "after")):
        ax.bar(x + (k - 1) * 0.25, [100 * report["fit"][name][s] for s in SENSORS], 0.25, label=name)
    ax.scatter(x, [100 * report["noise"][s] for s in SENSORS], color="k", marker="_", s=400, label="noise ceiling")
    ax.set_xticks(x, SENSORS)
    ax.set_yscale("log")
    ax.set_ylabel("held-out NRMSE, %")
    ax.legend(fontsize=8)
    return _png(fig)


def _overlays(analyser: GapAnalyser) -> str:
    import matplotlib.pyplot as plt

    a = analyser.aligned_
    idx = np.flatnonzero(a.holdout_mask)
    run = idx[: int(np.argmax(np.diff(idx) > 1)) + 1] if np.any(np.diff(idx) > 1) else idx
    window = run[: int(OVERLAY_SECONDS * SAMPLE_RATE_HZ)]
    fig, axes = plt.subplots(len(SENSORS), 1, figsize=(9, 7), sharex=True)
    series = (("nominal", analyser.nominal_prediction_), ("calibrated", analyser.calibrated_.prediction),
              ("after", analyser.after_prediction_))
    for i, (ax, s) in enumerate(zip(axes, SENSORS)):
        ax.plot(a.t[window], a.measured[i, window], color="0.6", lw=1.5, label="measured")
        for name, pred in series:
            ax.plot(a.t[window], pred[i, window], lw=0.9, label=name)
        ax.set_ylabel(f"{s} [{UNITS[s]}]")
    axes[0].legend(fontsize=8, ncol=4)
    axes[-1].set_xlabel("t [s]")
    return _png(fig)


def _spectra(analyser: GapAnalyser) -> str:
    import matplotlib.pyplot as plt

    a = analyser.aligned_
    fig, axes = plt.subplots(1, len(SENSORS), figsize=(11, 3))
    for i, (ax, s) in enumerate(zip(axes, SENSORS)):
        for name, pred in (("calibrated", analyser.calibrated_.prediction), ("after", analyser.after_prediction_)):
            r = a.measured[i, a.used_mask] - pred[i, a.used_mask]
            f, pxx = signal.welch(r, fs=SAMPLE_RATE_HZ, nperseg=min(1024, r.size))
            ax.semilogy(f, pxx, lw=0.9, label=name)
        ax.set_title(f"{s} residual spectrum", fontsize=9)
        ax.set_xlabel("Hz")
    axes[0].legend(fontsize=8)
    return _png(fig)


def _correlations(analyser: GapAnalyser) -> str:
    import matplotlib.pyplot as plt

    a = analyser.aligned_
    lags = np.arange(-100, 101)
    u = a.voltage[a.used_mask] - a.voltage[a.used_mask].mean()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3))
    for i, s in enumerate(SENSORS):
        r = a.measured[i, a.used_mask] - analyser.after_prediction_[i, a.used_mask]
        r = r - r.mean()
        n = r.size
        acf = [np.dot(r[k:], r[: n - k]) / np.dot(r, r) for k in range(0, 101)]
        ccf = [np.dot(r[max(k, 0): n + min(k, 0)], u[max(-k, 0): n - max(k, 0)]) / (n * r.std() * u.std())
               for k in lags]
        axes[0].plot(np.arange(101) / SAMPLE_RATE_HZ, acf, label=s)
        axes[1].plot(lags / SAMPLE_RATE_HZ, ccf, label=s)
    bound = 1.96 / np.sqrt(int(a.used_mask.sum()))
    for ax, title in zip(axes, ("residual autocorrelation (final model)", "residual–command cross-correlation")):
        ax.axhspan(-bound, bound, color="0.9")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("lag [s]")
        ax.legend(fontsize=8)
    return _png(fig)


def _opinion(effect: dict) -> str:
    """The second opinion on one named effect, one line (empty when there is none)."""
    so = effect.get("second_opinion")
    if so is None:
        return ""
    said = (f"agrees ({', '.join(so['supporting'][:3])})" if so["agrees"]
            else f"does not corroborate (points at {', '.join(so['implicated'][:3]) or 'no catalog effect'})")
    return f"<br/><i>second opinion (sparse regression): {html.escape(said)}</i>"


def render_html(analyser: GapAnalyser) -> str:
    """The whole report as one self-contained HTML page."""
    import matplotlib

    matplotlib.use("Agg")
    report = analyser.report
    models = ("nominal", "calibrated", "after")
    rows = "".join(
        f"<tr><td>{s}</td>" + "".join(f"<td>{100 * report['fit'][k][s]:.2f}</td>" for k in models)
        + f"<td>{100 * report['noise'][s]:.2f}</td></tr>" for s in SENSORS)
    effects = "".join(f"<li><b>{html.escape(e['id'])}</b>: {html.escape(e['evidence'])}{_opinion(e)}</li>"
                      for e in report["effects"])
    relations = "".join(
        f"<tr><td>{r['relation']}</td><td>{html.escape(r['component'])}</td><td>{r['ratio']:.2f}</td>"
        f"<td>{'broken' if r['broken'] else 'holds'}</td><td>{html.escape(r['regime'])}</td>"
        f"<td>{r['share']:.2f}</td></tr>"
        for r in report["relations"])
    plots = [("Fit per sensor", _fit_bars(report)), ("Overlays on held-out data", _overlays(analyser)),
             ("Residual spectra", _spectra(analyser)), ("Residual correlations", _correlations(analyser))]
    figures = "".join(f"<h2>{t}</h2><img alt='{t}' src='data:image/png;base64,{p}'/>" for t, p in plots)
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>hydrowatch gap report</title>"
        "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}td,th{padding:2px 8px}</style></head><body>"
        f"<h1>Sim-to-real gap</h1><p>{html.escape(report['summary'])}</p>"
        f"<h2>Effects</h2><ul>{effects or '<li>none</li>'}</ul>"
        "<h2>Held-out NRMSE, %</h2><table><tr><th>sensor</th><th>nominal</th><th>calibrated</th><th>after</th>"
        f"<th>noise ceiling</th></tr>{rows}</table>"
        "<h2>Component relations (residual RMS / noise-only level)</h2><table><tr><th>relation</th>"
        f"<th>component</th><th>ratio</th><th></th><th>where</th><th>share</th></tr>{relations}</table>{figures}"
        f"<h2>Report (JSON)</h2><pre>{html.escape(json.dumps(report, indent=1))}</pre></body></html>"
    )


def write_html(analyser: GapAnalyser, path: str | Path) -> None:
    """Write :func:`render_html` to ``path``."""
    Path(path).write_text(render_html(analyser), encoding="utf-8")
