"""The cycles method: ``hydrowatch train --rig`` and ``score`` of a rig's cycles, one verdict per component.

A tiny synthetic wide-layout rig (two components varying independently, a few cycles) end to end through the
command line and MLflow; the real UCI rig's honest-split figures when the shared data folder is there."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hydrowatch.cli import main
from hydrowatch.errors import DataError
from hydrowatch.rig import data_root

RIG = """name = "tiny-cycles"
[window]
kind = "cycle"
length_s = 20.0
grid_hz = 1.0
[layout]
kind = "wide"
[channels.P]
unit = "bar"
role = "sensor"
rate_hz = 10.0
source = "P.txt"
recorded_hz = 10.0
[channels.Q]
unit = "L/min"
role = "sensor"
rate_hz = 1.0
source = "Q.txt"
[channels.T]
unit = "°C"
role = "condition"
rate_hz = 1.0
source = "T.txt"
[labels]
source = "labels.txt"
[labels.valve]
column = 0
values = [100, 80, 60]
healthy = 100
[labels.pump]
column = 1
values = [0, 1]
healthy = 0
"""


def write_rig_folder(folder: Path, valve: np.ndarray, pump: np.ndarray, seed: int) -> None:
    """Cycles of 20 s: P steps from 10 to 40 bar at 5 s and back at 12 s, its high level lower as the valve
    closes (valve % · 0.3 bar); Q falls 2 L/min with a pump leak; T drifts 1 °C; noise 0.2 of each unit."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    t = np.arange(200) / 10.0
    high = (t >= 5) & (t < 12)
    p = 10.0 + high[None, :] * (valve[:, None] * 0.3) + rng.normal(0, 0.2, (valve.size, 200))
    q = 20.0 - 2.0 * pump[:, None] + rng.normal(0, 0.2, (pump.size, 20))
    temperature = 40.0 + np.linspace(0, 1, valve.size)[:, None] + rng.normal(0, 0.2, (valve.size, 20))
    for name, matrix in (("P.txt", p), ("Q.txt", q), ("T.txt", temperature)):
        (folder / name).write_text("".join("\t".join(f"{v:.4f}" for v in row) + "\n" for row in matrix))
    (folder / "labels.txt").write_text("".join(f"{v:g}\t{k:g}\n" for v, k in zip(valve, pump)))


@pytest.fixture(scope="module")
def rig_data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path | str]:
    root = tmp_path_factory.mktemp("rig")
    (root / "rig.toml").write_text(RIG, encoding="utf-8")
    valve = np.tile([100.0, 100.0, 80.0, 80.0], 30)  # 120 cycles; valve 60 is declared but never trained
    pump = np.tile([0.0, 1.0, 1.0, 0.0, 0.0, 1.0], 20)
    write_rig_folder(root / "train", valve, pump, seed=0)
    write_rig_folder(root / "new", np.array([100.0, 80.0, 60.0, 60.0]), np.array([1.0, 0.0, 0.0, 1.0]), seed=1)
    (root / "mlruns").mkdir()
    return {"root": root, "uri": f"sqlite:///{root / 'mlruns' / 'mlflow.db'}"}


def _run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().out


def test_train_and_score_a_rig_give_a_verdict_per_component(
    rig_data: dict[str, Path | str], capsys: pytest.CaptureFixture[str]
) -> None:
    root, model = Path(rig_data["root"]), Path(rig_data["root"]) / "model"
    code, out = _run(capsys, "train", "--rig", root / "rig.toml", "--data", root / "train", "--out", model,
                     "--tracking-uri", rig_data["uri"], "--experiment", "rig", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["method"] == "cycles" and summary["rig"] == "tiny-cycles"
    assert set(summary["components"]) == {"valve", "pump"}
    # honest split (each class's last 30 % of cycles tested): every test cycle is named right or read unknown
    # (the open-set thresholds come from 8 calibration cycles per class), never another state
    for figures in summary["components"].values():
        assert figures["accuracy"] >= 0.9 and figures["accuracy"] + figures["unknown"] == pytest.approx(1.0)
    assert summary["states"][:3] == ["valve=100", "valve=80", "valve=60"]
    manifest = json.loads((model / "manifest.json").read_text())
    assert manifest["method"] == "cycles" and manifest["window"] == 20 and manifest["components"]["pump"] == ["0", "1"]

    import mlflow

    mlflow.set_tracking_uri(str(rig_data["uri"]))
    # registered under the rig's own name (issue 17): the plant's hydrowatch@champion is never created nor moved
    assert summary["model_uri"] == "models:/hydrowatch-tiny-cycles@champion"
    registered = {m.name for m in mlflow.MlflowClient().search_registered_models()}
    assert "hydrowatch-tiny-cycles" in registered and "hydrowatch" not in registered
    run = mlflow.get_run(summary["run_id"])
    assert run.data.params["rig"] == "tiny-cycles" and run.data.params["cycles"] == "120"
    assert run.data.metrics["accuracy.valve"] == summary["components"]["valve"]["accuracy"]
    assert {"macro_f1.pump", "unknown.valve", "recall.valve.80"} <= set(run.data.metrics)

    code, out = _run(capsys, "score", "--model", model, "--data", root / "new", "--json", "--log-run",
                     "--tracking-uri", rig_data["uri"], "--experiment", "rig-scoring")
    scored = json.loads(out)
    logged = mlflow.search_runs(experiment_names=["rig-scoring"], output_format="list")[0].data
    assert logged.metrics == {"cycles": 4.0, "unknown.valve": 0.5, "unknown.pump": 0.0, "accuracy.valve": 1.0,
                              "accuracy.pump": 1.0} and logged.params["rig"] == "tiny-cycles"
    assert code == 0 and scored["summary"]["cycles"] == 4 and len(scored["cycles"]) == 4
    first = scored["cycles"][0]["components"]
    assert first["valve"]["state"] == "100" and first["pump"]["state"] == "1"
    assert set(first["valve"]["probabilities"]) == {"100", "80"} and first["valve"]["probability"] > 0.9
    # valve 60: never trained, far below 80 → unknown, which is right for an untrained state
    for cycle in scored["cycles"][2:]:
        assert cycle["components"]["valve"]["state"] == "unknown"
        assert cycle["components"]["valve"]["truth"] == "unknown" and cycle["components"]["valve"]["novelty"] > 1
    assert scored["summary"]["accuracy"] == {"valve": 1.0, "pump": 1.0}

    # the registered model through mlflow.pyfunc: a DataFrame of cycles (grid samples, a cycle id, two machines)
    # gives per cycle and component the verdicts `score` gave
    from hydrowatch.io.rig_cycles import read_rig_data
    from hydrowatch.rig import load_rig

    rig = load_rig(root / "rig.toml")
    values = read_rig_data(root / "new", rig).values
    frame = pd.concat([pd.DataFrame({"machine": "rig1" if i < 2 else "rig2", "cycle": 10 + i,
                                     **dict(zip(rig.channels.names, cycle))}) for i, cycle in enumerate(values)])
    model = mlflow.pyfunc.load_model(summary["model_uri"])
    verdicts = model.predict(frame)
    assert list(verdicts.columns) == ["machine", "cycle", "component", "state", "probability", "novelty"]
    assert verdicts["machine"].tolist() == ["rig1"] * 4 + ["rig2"] * 4 and verdicts["cycle"].iloc[-1] == 13
    for row in verdicts.itertuples():
        expected = scored["cycles"][row.cycle - 10]["components"][row.component]
        assert row.state == expected["state"] and row.probability == pytest.approx(expected["probability"])
    with pytest.raises(DataError, match="machine rig2: cycle 13 must have 20 rows .* Got 19"):
        model.predict(frame.iloc[:-1])


def test_mlflow_names_come_from_the_rig_unless_given() -> None:
    """One rule for train, trainer, demo and the scorer (issue 17): the plant's ``hydrowatch``, a rig's
    ``hydrowatch-<rig>``; a flag given wins; ``--no-register`` registers nothing."""
    import argparse

    from hydrowatch.training.options import add_tracking_arguments, tracking_names

    parser = argparse.ArgumentParser()
    add_tracking_arguments(parser)
    assert tracking_names(parser.parse_args([])) == ("hydrowatch", "hydrowatch")
    assert tracking_names(parser.parse_args([]), "uci-hydraulic") == ("hydrowatch-uci-hydraulic",
                                                                      "hydrowatch-uci-hydraulic")
    given = parser.parse_args(["--model-name", "hydrowatch", "--experiment", "lab"])
    assert tracking_names(given, "uci-hydraulic") == ("lab", "hydrowatch")
    assert tracking_names(parser.parse_args(["--no-register"]), "uci-hydraulic")[1] is None


def test_a_rig_folder_scores_without_labels_and_a_recording_is_refused(
    rig_data: dict[str, Path | str], capsys: pytest.CaptureFixture[str]
) -> None:
    root = Path(rig_data["root"])
    model = root / "model"
    if not (model / "manifest.json").exists():
        pytest.skip("needs the bundle of test_train_and_score_a_rig_give_a_verdict_per_component")
    unlabelled = root / "unlabelled"
    unlabelled.mkdir()
    for name in ("P.txt", "Q.txt", "T.txt"):
        (unlabelled / name).write_text((root / "new" / name).read_text())
    code, out = _run(capsys, "score", "--model", model, "--data", unlabelled, "--json")
    scored = json.loads(out)
    assert code == 0 and scored["summary"]["accuracy"] == {"valve": None, "pump": None}
    assert "truth" not in scored["cycles"][0]["components"]["pump"]
    code = main(["train", "--rig", str(root / "rig.toml"), "--data", str(root / "train"), "--out", str(root / "x"),
                 "--method", "stats"])
    assert code == 2 and "--rig trains the cycles method" in capsys.readouterr().err
    from hydrowatch.training import load_bundle

    with pytest.raises(DataError, match="trains from a rig's cycles"):
        type(load_bundle(model).health_method).fit({}, None)  # type: ignore[arg-type]


UCI = data_root() / "uci-hydraulic"
BASELINE_HONEST = {"cooler": 1.0, "valve": 1.0, "pump": 1.0, "accumulator": 0.544}
"""docs/rigs.md, statistics + LDA on the honest split (the plain baseline)."""


@pytest.mark.skipif(not (UCI / "profile.txt").is_file(), reason=f"the UCI hydraulic data is not at {UCI}")
def test_the_real_rig_reaches_the_plain_baseline_per_component(tmp_path: Path) -> None:
    from hydrowatch.io.wide import read_cycles
    from hydrowatch.methods.cycles.train import component_data, component_states, evaluate_component
    from hydrowatch.rig import builtin_rig

    # the honest split's figures as fit_cycles reports them (evaluate_component), without its final fit on every
    # cycle (the tiny rig's tests cover that; here it would cost half the test's time)
    rig = builtin_rig("uci-hydraulic")
    cycles = read_cycles(UCI, rig)
    figures = {c: evaluate_component(rig, component_data(rig, cycles.values, cycles.labels, c),
                                     component_states(rig.label(c))) for c in BASELINE_HONEST}
    for component, baseline in BASELINE_HONEST.items():
        assert figures[component]["accuracy"] >= baseline - 0.005, (component, figures[component])
        assert figures[component]["unknown"] <= 0.01, (component, figures[component])  # known cycles stay known
    # issue 17: the accumulator's step shares and 2 discriminants read 86.3 % (82.2 % with plain transients), with the
    # trees' vote where the training covers the cycle's condition 86.1 % (one cycle less, 99.9 % on random folds); every
    # error is a neighbouring precharge (mostly 130 bar at cooler 100 % read 115 bar), nothing two levels away
    accumulator = figures["accumulator"]
    assert accumulator["features"] == "transients" and accumulator["accuracy"] == pytest.approx(0.861, abs=0.002)
    confusion = np.array(accumulator["confusion_matrix"])  # rows 130, 115, 100, 90; columns those, then unknown
    assert confusion[0, 2:].sum() == 0 and confusion[1, 2:].sum() == 0 and confusion[2, 0] == 0
    assert confusion[3, :3].sum() == 0


def test_demo_on_a_rig_imports_trains_replays_from_the_registry_and_reports(
    rig_data: dict[str, Path | str], capsys: pytest.CaptureFixture[str]
) -> None:
    root = Path(rig_data["root"])
    code, out = _run(capsys, "demo", "--rig", root / "rig.toml", "--data", root / "train", "--out", root / "demo",
                     "--tracking-uri", rig_data["uri"], "--json")
    summary = json.loads(out)
    assert code == 0 and summary["cycles"] == 120
    assert summary["imported"] == {"valve": {"100": 60, "80": 60}, "pump": {"0": 60, "1": 60}}
    assert summary["model_uri"] == "models:/hydrowatch-tiny-cycles@champion"
    # the replay reads the training cycles back through the registered model: nearly all right, never a wrong state
    # (the scorer and replay services, a bus of their own): every cycle's verdicts come back, equal to `score`'s
    for component, replayed in summary["replay"].items():
        assert replayed["accuracy"] >= 0.95, component
        assert sum(n for s, n in replayed["counts"].items() if s != "unknown") == round(replayed["accuracy"] * 120)
        assert replayed["cycles"] == 120 and replayed["offline_agreement"] == 1.0
    assert Path(summary["recording"]).name == "tiny-cycles.mcap" and summary["bus_seconds"] > 0
    html = (root / "demo" / "report.html").read_text()
    assert "Training: the honest split per component" in html and html.count("<img") == 2
    assert "Replay on the bus" in html
    assert len(json.loads((root / "demo" / "scores.json").read_text())["cycles"]) == 120

