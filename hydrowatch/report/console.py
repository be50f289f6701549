"""Output for people: the short summaries ``train``, ``score``, ``gap`` and ``demo`` print on a terminal.

The rule (README, docs/formats.md): a command prints JSON when asked (``--json``) or when its standard
output is not a terminal (a pipe, a file, a test capturing it), so scripts keep parsing what they
always got; on a terminal it prints a few lines saying what was done, the key numbers, where the
files are and what to open next. Each ``*_text`` function takes the very object the command would
print as JSON and returns those lines.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TextIO

from hydrowatch.report.fleet_table import HEALTHY, wear_text


def json_output(asked: bool, stream: TextIO | None = None) -> bool:
    """Whether a command prints JSON: with ``--json`` (``asked``), or when ``stream`` (default
    ``sys.stdout``) is not a terminal."""
    stream = sys.stdout if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return asked or not (callable(isatty) and isatty())


def _pct(value: float | None) -> str:
    """A fraction 0–1 as a percentage, ``n/a`` for None."""
    return "n/a" if value is None else f"{100 * value:.1f} %"


def _join(items: Mapping[str, Any], fmt: Callable[[Any], str] = str) -> str:
    """``k1 v1, k2 v2`` with each value through ``fmt``."""
    return ", ".join(f"{k} {fmt(v)}" for k, v in items.items())


def _num(spec: str) -> Callable[[Any], str]:
    """Formatter of numbers by format ``spec`` (``.3f``, ``.4g``); other values as they are."""
    return lambda v: format(v, spec) if isinstance(v, int | float) else str(v)


def train_text(summary: Mapping[str, Any]) -> str:
    """Lines for one trained bundle (``hydrowatch train``'s JSON summary)."""
    method = summary["method"] if summary.get("reference") in (None, summary["method"]) else (
        f"{summary['method']} ({summary['reference']} reference)")
    recall: dict[str, float] = summary.get("per_class_recall") or {}
    lines = [f"trained {method} model {summary['version'][:19]}… on {len(summary['states'])} states "
             f"in {summary['seconds']:.1f} s",
             f"  test accuracy {_pct(summary['test_accuracy'])} on {summary['test_windows']} windows"
             + (f"; weakest recall {min(recall, key=lambda k: recall[k])} {_pct(min(recall.values()))}" if recall
                else "")]
    if summary.get("checks"):
        lines.append(f"  accuracy on other commands: {_join(summary['checks'], _pct)}")
    if summary.get("nrmse_one_step"):
        lines.append(f"  one-step NRMSE of the reference models: {_join(summary['nrmse_one_step'], _num('.3f'))}")
    registered = f", registered {summary['model_uri']} (version {summary['registered_version']})" if summary.get(
        "model_uri") else ""
    lines.append(f"  bundle {summary['out']}; MLflow run {summary['run_id']} in {summary['tracking_uri']}{registered}")
    return "\n".join(lines)


def train_next(out: str, tracking_uri: str, runs_url: str | None = None) -> str:
    """The closing line of ``hydrowatch train``: what to run next; ``runs_url``: the runs table to open (a server's
    address, or ``mlflow ui``'s once started)."""
    served = tracking_uri.startswith(("http://", "https://"))
    runs = "" if served else f"mlflow ui --backend-store-uri {tracking_uri}"
    if runs_url:
        runs += f"{', then ' if runs else ''}open {runs_url}"
    return f"next: hydrowatch score --model {out} --data RECORDINGS; the runs: {runs or tracking_uri}"


def score_text(result: Mapping[str, Any]) -> str:
    """Lines for one scored recording (``hydrowatch score --json``'s object)."""
    s = result["summary"]
    counts = dict(sorted(s["counts"].items(), key=lambda kv: -kv[1]))
    accuracy = "" if s["accuracy"] is None else f"; accuracy {_pct(s['accuracy'])} against its labels"
    lines = [f"{result['source']}: {s['windows']} windows: {_join(counts)}{accuracy}"]
    judged = [w for w in result["windows"] if w["state"] != "invalid"]
    if judged:
        last = judged[-1]
        p = "" if last.get("probability") is None else f" (p = {last['probability']:.2f})"
        lines.append(f"  last verdict, window from {last['start_s']:.1f} s: {last['state']}{p}")
    elif result["windows"]:
        lines.append(f"  no window could be judged: {result['windows'][0].get('reason', 'invalid')}")
    for fault, f in (s.get("forecast") or {}).items():
        if f.get("alert_in_s") is not None:
            lo, hi = ("open" if v is None else v for v in f["ci95"])
            either = f" (or {f['untold_from']}: not yet told apart)" if f.get("untold_from") else ""
            lines.append(f"  {fault}: alert in {f['alert_in_s']:.1f} operating s after the last window "
                         f"(95 %: {lo}–{hi} s){either}")
    return "\n".join(lines)


SCORE_NEXT = "next: --json for every window's verdict, probabilities and relative entropies"


def gap_text(report: Mapping[str, Any], source: str, written: Sequence[str]) -> str:
    """Lines for a sim-to-real analysis (``hydrowatch gap``'s report) of ``source``; ``written``: files made."""
    lines = [f"sim-to-real gap of {source}: " + ("mismatch found" if report["mismatch"] else "no mismatch")]
    for effect in report["effects"]:
        params = _join(effect.get("parameters") or {}, _num(".4g"))
        lines.append(f"  missing physics: {effect['id']}" + (f" ({params})" if params else ""))
    for row in report["located"][:3]:
        lines.append(f"  located: {row['sensor']} in {row['regime']} ({_pct(row['share'])} of the samples)")
    fit = report["fit"]
    lines.append("  held-out NRMSE nominal → calibrated → after: " + ", ".join(
        f"{s} {fit['nominal'][s]:.3f} → {fit['calibrated'][s]:.3f} → {fit['after'][s]:.3f}" for s in fit["nominal"]))
    first = re.match(r"(.+?[.!?])(?=\s+[A-Z]|$)", report["summary"], re.S)
    lines.append(f"  {first.group(1) if first else report['summary']}"
                 + (" (the rest in the report's summary)" if first and first.group(1) != report["summary"] else ""))
    lines.append(f"  wrote {', '.join(written)}")
    html = [w for w in written if w.endswith(".html")]
    lines.append(f"next: open {html[0]}" if html else "next: add --html OUT.html for the plots")
    return "\n".join(lines)


def demo_text(summary: Mapping[str, Any]) -> str:
    """Lines for ``hydrowatch demo``'s summary: the fleet first, then the models, then where things are."""
    fleet = summary["fleet"]
    attention = summary.get("attention") or [{"machine": m, "state": s} for m, s in sorted(fleet.items())
                                             if s != HEALTHY]
    lines = [f"hydrowatch demo finished in {summary['seconds']:.0f} s: "
             f"{len(attention)} of {len(fleet)} machines need attention"]
    for a in attention:
        since = f" since {a['since_s']:.0f} s" if a.get("since_s") is not None else ""
        lines.append(f"  {a['machine']:<8} {a['state']}{since}" + (f": {a['why']}" if a.get("why") else ""))
    healthy = [m for m, s in sorted(fleet.items()) if s == HEALTHY]
    if healthy:
        lines.append(f"  healthy: {', '.join(healthy)}")
    for machine, parts in (summary.get("wear") or {}).items():  # soonest alert first
        soon = [wear_text(f, p) for f, p in parts.items() if p.get("alert_in_s") is not None]
        lines.append(f"  {machine:<8} wear: {'; '.join(soon)}")
    lines.append(f"models (accuracy on held-out commands; champion: {summary['champion']}):")
    for kind, checks in summary["accuracy"].items():
        lines.append(f"  {kind:<8} {_join(checks, _pct)}" if checks else f"  {kind}")
    training: Mapping[str, Any] = next(iter(summary["training"].values()), {})
    runs = f", runs table {training['runs_url']}" if training.get("runs_url") else ""
    lines.append(f"files: {summary['out']}/ (models, recordings, logs); MLflow {training.get('tracking_uri', '')}"
                 + runs)
    lines.append(f"next: open {summary['report']}")
    return "\n".join(lines)


__all__ = ["SCORE_NEXT", "demo_text", "gap_text", "json_output", "score_text", "train_next", "train_text"]
