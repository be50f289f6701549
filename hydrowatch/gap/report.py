"""The ``hydrowatch gap`` report (contract.md) and the saved model, from the analysis' fits.

Report keys of the contract: ``mismatch``, ``effects``, ``located``, ``fit`` (held-out NRMSE of
the nominal, calibrated and final model per sensor), ``calibrated_parameters``, ``summary``.
Additions (docs/gap.md): ``noise`` (the noise ceiling as NRMSE), ``experiments`` (effects this
recording cannot show and the run that would), ``trials`` (every candidate judged),
``identifiability`` (which calibrated parameters the recording determines, identify.py) and
``discovery_test`` (the test of discovery.py on the calibrated and the final model).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import OutputErrorFit
from hydrowatch.gap.diagnose import Diagnosis, Trial
from hydrowatch.gap.discovery import ResidualTest
from hydrowatch.gap.discrepancy import MODEL_SCHEMA, Discrepancy, SensorCorrection, load_model
from hydrowatch.gap.identify import Identifiability
from hydrowatch.gap.locate import noise_std, nrmse, regimes, strongest_regime
from hydrowatch.gap.relations import RELATIONS, RelationCheck, describe
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS

if TYPE_CHECKING:
    from hydrowatch.gap.analysis import Unidentified
    from hydrowatch.gap.second_opinion import SecondOpinion

EXCESS_RATIO = 1.15
"""A sensor is mismatched when its held-out NRMSE exceeds its noise ceiling by this factor."""


def fit_table(aligned: AlignedRecording, prediction: np.ndarray) -> dict[str, float]:
    """Held-out NRMSE per sensor, ``{sensor: nrmse}``."""
    return {s: round(nrmse(aligned.measured[i], prediction[i], aligned.holdout_mask), 5) for i, s in enumerate(SENSORS)}


def noise_ceiling(aligned: AlignedRecording, prediction: np.ndarray) -> dict[str, float]:
    """NRMSE a perfect model would reach: the sensor noise std over the signal std, per sensor."""
    out = {}
    for i, s in enumerate(SENSORS):
        r = aligned.measured[i, aligned.used_mask] - prediction[i, aligned.used_mask]
        out[s] = round(noise_std(r) / float(aligned.scale[i]), 5)
    return out


RELATION_OUTPUT = {"load": "torque", "motor": "flow", "valve": "flow"}
"""The sensor each component relation predicts (the ``sensor`` of its ``located`` entry)."""


def located(aligned: AlignedRecording, prediction: np.ndarray, noise: dict[str, float],
            relations: Sequence[RelationCheck] = ()) -> list[dict[str, Any]]:
    """Mismatched sensors, largest excess first, each with the region that holds most of its error; then
    the broken component relations, most broken first (``relation``, ``component``, ``ratio`` added)."""
    fit = fit_table(aligned, prediction)
    mask = aligned.used_mask
    rows = []
    for i, s in enumerate(SENSORS):
        if fit[s] <= EXCESS_RATIO * noise[s]:
            continue
        r = aligned.measured[i, mask] - prediction[i, mask]
        noise_var = (noise[s] * aligned.scale[i]) ** 2
        found = regimes(r, aligned.voltage[mask], prediction[1, mask], prediction[2, mask], noise_var)
        best = strongest_regime(found)
        rows.append((fit[s] ** 2 - noise[s] ** 2, {"sensor": s, "regime": best.label, "share": round(best.share, 3)}))
    rows.sort(key=lambda row: -row[0])
    broken = sorted((c for c in relations if c.broken), key=lambda c: -c.ratio)
    return [row for _, row in rows] + [
        {"sensor": RELATION_OUTPUT[c.name], "regime": c.regime.label, "share": round(c.regime.share, 3),
         "relation": c.name, "component": RELATIONS[c.name], "ratio": round(c.ratio, 3)} for c in broken]


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _effect_entry(aligned: AlignedRecording, trial: Trial, before: np.ndarray, final: OutputErrorFit
                  ) -> dict[str, Any]:
    c = trial.refit.candidate
    params = {k: round(float(v), 6) for k, v in final.effects[c.id].items()}
    cis = []
    for p in c.free:
        lo, hi = final.ci95.get(f"{c.id}.{p}", (float("nan"), float("nan")))
        cis.append(f"{p} = {params[p]:.4g} (95 % CI {lo:.4g}…{hi:.4g})")
    b, a = fit_table(aligned, before), fit_table(aligned, trial.refit.fit.prediction)
    sensor = max(SENSORS, key=lambda s: b[s] - a[s])
    evidence = (f"held-out cost −{_pct(trial.gain)} (± {_pct(trial.gain_se)}; lower in 1 s blocks at "
                f"z = {trial.consistency:.1f}), ΔBIC {trial.delta_bic:.0f}; "
                f"{', '.join(cis)}; held-out {sensor} NRMSE {_pct(b[sensor])} → {_pct(a[sensor])}")
    return {"id": c.id, "parameters": params, "evidence": evidence}


def _unidentified_entry(u: Unidentified, where: str) -> dict[str, Any]:
    terms = sorted(u.correction.terms_.items(), key=lambda kv: -abs(kv[1]))
    names = ", ".join(name for name, _ in terms[:4])
    if u.applied:
        evidence = (f"no catalog effect passed; {u.sensor} error lives in {where}; a sparse correction over "
                    f"[{names}] cuts its held-out error by {_pct(u.correction.holdout_gain_)}")
    else:
        evidence = (f"no catalog effect passed; {u.sensor} error lives in {where} and is beyond sensor noise and "
                    "parameter uncertainty (discovery test), but no term of the correction library describes it "
                    f"(the best sparse correction cuts {_pct(max(u.correction.holdout_gain_, 0.0))}); no correction "
                    "is applied")
        terms = []
    return {"id": "unidentified", "parameters": {"sensor": u.sensor, **{k: round(v, 6) for k, v in terms}},
            "evidence": evidence}


def calibrated_table(nominal: PlantParameters, calibrated: OutputErrorFit,
                     determined: Sequence[str] | None = None) -> dict[str, Any]:
    """``{name: {"value", "ci95", "nominal", "ratio", "determined"}}`` for every calibrated parameter
    (SI units); ``determined`` says whether the recording determines it (identify.py; all when None)."""
    out = {}
    for name, value in calibrated.values.items():
        lo, hi = calibrated.ci95[name]
        ref = getattr(nominal, name)
        out[name] = {"value": float(value), "ci95": [float(lo), float(hi)], "nominal": ref,
                     "ratio": round(float(value) / ref, 4), "determined": determined is None or name in determined}
    return out


def _parameter_changes(table: dict[str, Any]) -> str:
    moved = [f"{n} ×{row['ratio']:.2f}" for n, row in table.items() if row["determined"]
             and abs(row["ratio"] - 1) > 0.05 and not (row["ci95"][0] <= row["nominal"] <= row["ci95"][1])]
    return ", ".join(moved) if moved else "none beyond 5 %"


def _not_determined(identifiability: Identifiability | None) -> str:
    """The summary's sentence on what the recording leaves open, with the experiments that would not."""
    if identifiability is None or not identifiability.undetermined:
        return ""
    by_experiment: dict[str, list[str]] = {}
    for name, row in identifiability.undetermined.items():
        by_experiment.setdefault(str(row["experiment"]), []).append(name)
    return ("Not determined by this recording (held near the design values): " + "; ".join(
        f"{', '.join(names)}, which need {text}" for text, names in by_experiment.items()) + ".")


def _fits(fit: dict[str, float]) -> str:
    return ", ".join(f"{s} {_pct(v)}" for s, v in fit.items())


def build_report(aligned: AlignedRecording, nominal: PlantParameters, nominal_prediction: np.ndarray,
                 calibrated: OutputErrorFit, diagnosis: Diagnosis, unidentified: list[Unidentified],
                 after_prediction: np.ndarray, relations: list[RelationCheck],
                 opinions: Sequence[SecondOpinion] = (), identifiability: Identifiability | None = None,
                 tests: Mapping[str, ResidualTest] | None = None) -> dict[str, Any]:
    """The report dict (module docstring), with a plain-language summary carrying the numbers.

    ``opinions``: the second opinion on the residual each accepted effect met (the calibrated one
    first; second_opinion.py); each named effect gets its ``second_opinion`` verdict.
    ``identifiability`` (identify.py) and ``tests`` (discovery.py: ``calibrated`` and ``final``)
    add the report's ``identifiability`` and ``discovery_test``.
    """
    noise = noise_ceiling(aligned, after_prediction)
    where = located(aligned, calibrated.prediction, noise, relations)
    effects = []
    before = calibrated.prediction
    for k, trial in enumerate(diagnosis.accepted):
        effects.append(_effect_entry(aligned, trial, before, diagnosis.final))
        if k < len(opinions):
            effects[-1]["second_opinion"] = opinions[k].verdict(trial.refit.candidate.id)
        before = trial.refit.fit.prediction
    regime_of = {row["sensor"]: row["regime"] for row in where}
    effects += [_unidentified_entry(u, regime_of.get(u.sensor, "no single regime")) for u in unidentified]
    fit = {"nominal": fit_table(aligned, nominal_prediction), "calibrated": fit_table(aligned, calibrated.prediction),
           "after": fit_table(aligned, after_prediction)}
    table = calibrated_table(nominal, calibrated, None if identifiability is None else identifiability.determined)
    keys = ("gain", "gain_se", "consistency", "delta_bic", "explained", "worst_sensor", "improved", "distinct")
    trials = [[{"effect": t.refit.candidate.label, "gain": round(t.gain, 4), "gain_se": round(t.gain_se, 4),
                "consistency": round(t.consistency, 2), "delta_bic": round(t.delta_bic, 1),
                "explained": round(t.explained, 3), "worst_sensor": round(t.worst_sensor, 3), "improved": t.improved,
                "distinct": t.distinct, "passed": t.passed, "added": any(t is a for a in diagnosis.accepted)}
               for t in rnd]
              + [{"effect": label, **dict.fromkeys(keys), "passed": False, "added": False} for label in out]
              for rnd, out in zip(diagnosis.rounds, diagnosis.scanned_out)]
    report = {
        "mismatch": bool(effects), "effects": effects, "located": where, "fit": fit,
        "calibrated_parameters": table, "relations": [c.as_dict() for c in relations], "noise": noise,
        "experiments": dict(diagnosis.unrevealable), "trials": trials, "dropped": list(diagnosis.dropped),
        "second_opinion": opinions[0].as_dict() if opinions else None,
    }
    if identifiability is not None:
        report["identifiability"] = identifiability.as_dict()
    if tests is not None:
        report["discovery_test"] = {k: v.as_dict() for k, v in tests.items()}
    report["summary"] = " ".join(p for p in (summary(report, _parameter_changes(table), describe(list(relations))),
                                             _not_determined(identifiability)) if p)
    return report


def summary(report: dict[str, Any], changes: str, relations: str = "") -> str:
    """One paragraph in plain words with the numbers (gap-method.md, "Reporting")."""
    fit, noise = report["fit"], report["noise"]
    parts = []
    if report["mismatch"]:
        names = ", ".join(e["id"] if e["id"] != "unidentified"
                          else f"an unidentified effect in {e['parameters']['sensor']}" for e in report["effects"])
        parts.append(f"Missing physics: {names}.")
        sensors = [row for row in report["located"] if "relation" not in row]
        if sensors:
            loc = "; ".join(f"{row['sensor']} error mostly in {row['regime']} (share {row['share']:.2f})"
                            for row in sensors)
            parts.append(f"After calibration the {loc}.")
        parts.append(relations)
        for e in report["effects"]:
            parts.append(f"{e['id']}: {e['evidence']}.")
        parts.append(_second_opinion_sentence(report["effects"]))
        parts.append(f"Held-out NRMSE calibrated {_fits(fit['calibrated'])} → with the effects {_fits(fit['after'])} "
                     f"(noise ceiling {_fits(noise)}).")
    else:
        above = [s for s in fit["after"] if fit["after"][s] > EXCESS_RATIO * noise[s]]
        if above:
            parts.append(f"No missing physics named: no candidate effect or data-driven correction passed, but the "
                         f"error of {', '.join(above)} stays above the noise level (held-out NRMSE "
                         f"{_fits(fit['after'])}; noise ceiling {_fits(noise)}); a longer or richer recording may "
                         "resolve it.")
        else:
            parts.append("No missing physics: no candidate effect passed and the remaining error is at the noise "
                         f"level (held-out NRMSE {_fits(fit['after'])}; noise ceiling {_fits(noise)}).")
    if not report["mismatch"]:
        parts.append(relations)
    parts.append(f"Nominal model NRMSE {_fits(fit['nominal'])}; calibrated parameter changes: {changes}.")
    if report["experiments"]:
        parts.append("Not testable with this recording: " + "; ".join(
            f"{k} needs {v}" for k, v in report["experiments"].items()) + ".")
    return " ".join(p for p in parts if p)


def _second_opinion_sentence(effects: list[dict[str, Any]]) -> str:
    """How the sparse regression's stable terms read the named effects (corroboration, not a rule)."""
    judged = [e for e in effects if "second_opinion" in e]
    if not judged:
        return ""
    parts = []
    for e in judged:
        so = e["second_opinion"]
        if so["agrees"]:
            freq = [so["selection_frequency"][s.split(": ", 1)[0]][s.split(": ", 1)[1]] for s in so["supporting"]]
            parts.append(f"agrees on {e['id']} ({', '.join(so['supporting'][:3])}; selected in "
                         f"{_pct(min(freq))}–{_pct(max(freq))} of the resampled fits"
                         f"{'' if so['specific'] else '; shared with other dynamic effects'})")
        else:
            found = ", ".join(so["implicated"]) or "no catalog signature"
            parts.append(f"does not corroborate {e['id']} (its stable terms point at {found})")
    return ("Second opinion (stability-selected sparse regression on the residual): " + "; ".join(parts)
            + "; it corroborates, it does not decide.")


def model_config(final: OutputErrorFit, unidentified: list[Unidentified]) -> dict[str, Any]:
    """The augmented model as a simulator configuration (docs/gap.md, "Saved model")."""
    effects = {k: {p: float(v) for p, v in vals.items()} for k, vals in final.effects.items()}
    cli = ";".join(f"{k}:" + ",".join(f"{p}={v:.6g}" for p, v in vals.items()) for k, vals in effects.items())
    config: dict[str, Any] = {"schema": MODEL_SCHEMA, "parameters": final.parameters.to_dict(), "effects": effects,
                              "effects_cli": cli}
    applied = [u for u in unidentified if u.applied]
    if applied:
        discrepancy = Discrepancy(tuple(SensorCorrection(u.sensor, dict(u.correction.terms_), u.correction.settings_)
                                        for u in applied))
        config["corrections"] = discrepancy.to_config()
    return config


def read_model(path: str | Path) -> tuple[PlantParameters, dict[str, dict[str, float]]]:
    """Plant parameters and effects from a saved model (MODEL_SCHEMA) or a flat parameters JSON file.

    The model's output corrections (its discrepancy stage) are read by
    :func:`hydrowatch.gap.discrepancy.load_model`, which also gives these two.

    Raises
    ------
    ParameterError
        Unreadable JSON, unknown parameter names or effects out of the catalog's ranges.
    """
    model = load_model(path)
    return model.parameters, model.effects
