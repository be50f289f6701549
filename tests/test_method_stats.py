"""The baseline method (per-window statistics + logistic regression) through the CLI, the report, MLflow and the
scorer service: a third method that needs no edit outside its package but one registration line (issue 13)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_pipeline_online import scorer_round_trip

from hydrowatch.cli import main
from hydrowatch.io import read_recording, write_recording
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.online import Chunk, OnlineScorer

STATES = ["healthy", "load_alert", "pump_leak_warning", "motor_leak_alert"]
TRAINED = ["healthy", "load_alert", "motor_leak_alert", "pump_leak_warning"]
"""The states in the bundle's order: healthy, then the others as the files are read (sorted names)."""
SENSORS = ["flow", "speed", "torque"]


@pytest.fixture(scope="module")
def stats(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """40 s per state (seed 0) → ``train --method stats`` (tracked, registered, report kept); 30 s per state of
    another seed to score."""
    root = tmp_path_factory.mktemp("stats")
    data, test = root / "data", root / "test"
    data.mkdir()
    test.mkdir()
    for r in simulate_states(STATES, seconds=40, seed=0):
        write_recording(r, data / f"{r.state}.mcap")
    for r in simulate_states(STATES, seconds=30, seed=11):
        write_recording(r, test / f"{r.state}.parquet")
    uri = f"sqlite:///{root / 'mlflow.db'}"
    return {"root": root, "data": data, "test": test, "uri": uri, "out": root / "model", "report": root / "report"}


@pytest.fixture(scope="module")
def trained(stats: dict) -> dict:
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        code = main(["train", "--data", str(stats["data"]), "--out", str(stats["out"]), "--method", "stats",
                     "--report", str(stats["report"]), "--tracking-uri", stats["uri"], "--experiment", "test",
                     "--json"])
    assert code == 0
    return json.loads(buffer.getvalue())


def test_train_stats_writes_a_bundle_a_report_and_an_mlflow_run(stats: dict, trained: dict) -> None:
    assert trained["method"] == "stats" and trained["reference"] is None and trained["states"] == TRAINED
    assert trained["sensors"] == SENSORS and trained["nrmse_one_step"] == {}
    assert trained["test_accuracy"] >= 0.75 and trained["test_windows"] == len(STATES)  # 6 s held out per state
    manifest = json.loads((stats["out"] / "manifest.json").read_text())
    assert manifest["method"] == "stats" and manifest["window"] == manifest["hop"] == 1000
    assert (stats["out"] / "stats" / "model.json").is_file() and manifest["version"].startswith("sha256:")
    table = (stats["report"] / "relative_entropy.csv").read_text().splitlines()
    assert table[0] == "window state,sensor," + ",".join(TRAINED) and len(table) == 1 + len(STATES) * len(SENSORS)
    assert (stats["report"] / "confusion_matrix.png").is_file() and not (stats["report"] / "errors_flow.png").exists()

    import mlflow

    mlflow.set_tracking_uri(stats["uri"])
    run = mlflow.get_run(trained["run_id"])
    assert run.data.params["method"] == "stats" and run.data.params["plan.window"] == "1000"
    assert run.data.tags["method"] == "stats" and run.info.run_name.startswith("stats-")
    assert run.data.metrics["test_accuracy"] == trained["test_accuracy"] and "recall.load_alert" in run.data.metrics
    model_id = run.outputs.model_outputs[0].model_id  # the bundle is the run's MLflow model (artifacts/bundle)
    files = {a.path for a in mlflow.MlflowClient().list_logged_model_artifacts(model_id, "artifacts/bundle")}
    assert "artifacts/bundle/manifest.json" in files and trained["model_uri"] == "models:/hydrowatch@champion"


def test_score_stats_json_on_another_seed(stats: dict, trained: dict, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["score", "--model", "models:/hydrowatch@champion", "--tracking-uri", stats["uri"],
                 "--data", str(stats["test"]), "--json"]) == 0
    results = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(results) == len(STATES)
    for result in results:
        windows = result["windows"]
        assert result["summary"]["windows"] == len(windows) == 6
        assert result["summary"]["model_version"] == "hydrowatch/v1"
        assert set(windows[0]["kl"]) == set(SENSORS) and set(windows[0]["kl"]["flow"]) == set(STATES)
        assert "degradation" not in windows[0] and "forecast" not in result["summary"]
        assert result["summary"]["accuracy"] >= 0.8, result["source"]
    pooled = ["score", "--model", str(stats["out"]), "--data", str(stats["test"]), "--json", "--smoothing", "3"]
    assert main(pooled) != 0
    assert "smoothing must be an integer >= 1, and 1 for a bundle" in capsys.readouterr().err


def test_online_verdicts_equal_the_offline_ones_and_a_gap_invalidates(stats: dict, trained: dict) -> None:
    from hydrowatch.training.scoring import score_recording

    bundle = ModelBundle.load(stats["out"])
    r = read_recording(stats["test"] / "load_alert.parquet")
    scorer = OnlineScorer(bundle)
    assert scorer.columns == ["voltage", *SENSORS]
    got = []
    for k in range(0, len(r), 100):
        if k == 2500:
            continue  # a missing chunk: the window in progress is invalid
        got += scorer.update([Chunk("f/m", r.t[k:k + 100], {c: r[c][k:k + 100] for c in scorer.columns})])
    offline = score_recording(bundle, r)["windows"]
    assert [v.verdict.state for v in got[:2]] == [w["state"] for w in offline[:2]]
    assert got[2].verdict.state == "invalid" and "gap" in str(got[2].verdict.reason)
    assert np.allclose(got[0].scores, [[offline[0]["kl"][s][k] for k in TRAINED] for s in SENSORS])


def test_scorer_service_with_a_stats_bundle(stats: dict, trained: dict) -> None:
    machines = [read_recording(stats["test"] / f"{s}.parquet") for s in STATES[:2]]
    for m, s in zip(machines, STATES):
        m.meta["state"] = s
    code, got, first_kl = scorer_round_trip(stats["out"], machines, ("voltage", *SENSORS), 2200, 4)
    assert code == 0 and set(got) == set(STATES[:2])
    assert all(rows[0]["window_end"] - rows[0]["window_start"] == pytest.approx(5.0) for rows in got.values())
    assert first_kl is not None and set(first_kl.batch.column("sensor").to_pylist()) == set(SENSORS)


def test_the_report_section_of_a_stats_run(stats: dict) -> None:
    from hydrowatch.io import read_recording as read
    from hydrowatch.report.training import training_section
    from hydrowatch.training.options import TrainingSettings
    from hydrowatch.training.trainer import train

    grouped = {s: [read(Path(stats["data"]) / f"{s}.mcap")] for s in STATES}
    result = train(grouped, TrainingSettings(method="stats"))
    html = "".join(training_section(result, "stats").parts)
    assert result.bundle.method == "stats" and result.evaluation["test_accuracy"] >= 0.9
    assert "Window statistics + logistic regression (baseline); test accuracy" in html
    assert "<th>sensor</th>" in html and "NRMSE" not in html
