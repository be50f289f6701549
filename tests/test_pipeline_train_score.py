"""End to end: simulate → ``hydrowatch train`` (MLflow in a tmp sqlite store) → ``hydrowatch score --json``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hydrowatch.cli import main
from hydrowatch.io import write_recording
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.options import DEMO_PLAN

STATES = ["healthy", "load_alert", "pump_leak_warning", "motor_leak_alert"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Identification data of 4 states (small plan), a Box-Jenkins bundle trained, tracked and registered."""
    root = tmp_path_factory.mktemp("pipeline")
    data, test = root / "data", root / "test"
    data.mkdir()
    test.mkdir()
    seconds = DEMO_PLAN.samples_per_state / 200 + 1
    for r in simulate_states(STATES, seconds=seconds, seed=0):
        write_recording(r, data / f"{r.state}.mcap")
    for r in simulate_states(STATES, seconds=30, seed=11):  # another seed: data the model never saw
        write_recording(r, test / f"{r.state}.parquet")
    uri = f"sqlite:///{root / 'mlruns' / 'mlflow.db'}"
    (root / "mlruns").mkdir()
    return {"root": root, "data": data, "test": test, "uri": uri}


def test_train_prints_summary_and_registers(trained: dict, capsys: pytest.CaptureFixture[str]) -> None:
    out = trained["root"] / "model"
    assert main(["train", "--data", str(trained["data"]), "--out", str(out), "--method", "entropy", "--reference", "bj",
                 "--tracking-uri", trained["uri"], "--experiment", "test"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["states"][0] == "healthy" and set(summary["states"]) == set(STATES)
    assert summary["test_accuracy"] >= 0.95
    assert all(0 < v < 0.5 for v in summary["nrmse_one_step"].values())
    assert summary["model_uri"] == "models:/hydrowatch@champion" and summary["registered_version"] == "1"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["reference"] == "bj" and manifest["window"] == 1000 and manifest["version"].startswith("sha256:")

    import mlflow

    mlflow.set_tracking_uri(trained["uri"])
    run = mlflow.get_run(summary["run_id"])
    assert run.data.params["bj.nb"] == "3" and run.data.params["plan.window"] == "1000"
    assert run.data.metrics["test_accuracy"] == summary["test_accuracy"]
    assert {"nrmse.flow", "Q.speed", "recall.load_alert"} <= set(run.data.metrics)
    # the run spans the training (MLflow shows its duration), in an experiment MLflow opens as model training
    assert (run.info.end_time - run.info.start_time) / 1000 >= summary["seconds"] - 0.05  # seconds rounded to 0.1
    experiment = mlflow.MlflowClient().get_experiment(run.info.experiment_id)
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    artifacts = {a.path for a in mlflow.MlflowClient().list_artifacts(run.info.run_id, "report")}
    assert {"report/confusion_matrix.png", "report/errors_speed.png", "report/relative_entropy.csv"} <= artifacts


def test_score_json_on_a_separate_seed(trained: dict, capsys: pytest.CaptureFixture[str]) -> None:
    model = trained["root"] / "model"
    if not model.exists():
        pytest.skip("needs test_train_prints_summary_and_registers")
    capsys.readouterr()
    assert main(["score", "--model", "models:/hydrowatch@champion", "--tracking-uri", trained["uri"],
                 "--data", str(trained["test"]), "--json"]) == 0
    results = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(results) == len(STATES)
    judged = right = 0
    for result in results:
        state = Path(result["source"]).stem
        windows = result["windows"]
        assert result["summary"]["windows"] == len(windows) >= 10
        assert result["summary"]["model_version"] == "hydrowatch/v1"
        first = windows[0]
        assert set(first) >= {"start_s", "state", "probabilities", "kl"}
        assert set(first["kl"]) == {"flow", "speed", "torque"} and set(first["kl"]["speed"]) == set(STATES)
        assert "degradation" not in first and "forecast" not in result["summary"]  # entropy: no physical estimate
        assert abs(sum(first["probabilities"].values()) - 1.0) < 1e-6
        judged += len(windows)
        right += sum(w["state"] == state for w in windows)
    assert right / judged >= 0.9, right / judged


def test_score_short_file_is_invalid_and_unlabelled_train_data_is_an_error(
        trained: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = trained["root"] / "model"
    if not model.exists():
        pytest.skip("needs test_train_prints_summary_and_registers")
    short = next(simulate_states(["healthy"], seconds=3, seed=2))
    write_recording(short, tmp_path / "short.csv")
    capsys.readouterr()
    assert main(["score", "--model", str(model), "--data", str(tmp_path / "short.csv"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [w["state"] for w in result["windows"]] == ["invalid"]
    assert "too short" in result["windows"][0]["reason"]
    assert result["summary"]["accuracy"] is None
    short.meta["state"] = None
    write_recording(short, tmp_path / "unlabelled.csv")
    assert main(["train", "--data", str(tmp_path / "unlabelled.csv"), "--out", str(tmp_path / "m")]) == 2
    assert "health label" in capsys.readouterr().err


def test_default_train_fits_box_jenkins_narx_and_parity(trained: dict, capsys: pytest.CaptureFixture[str]) -> None:
    """The contract's ``train``: Box-Jenkins and NARX reference models (two runs), then the parity bundle,
    which ``score --model OUT`` takes as the folder's default."""
    out = trained["root"] / "all"
    capsys.readouterr()
    assert main(["train", "--data", str(trained["data"]), "--out", str(out), "--narx", "2,2,3", "--narx-iterations",
                 "5", "--tracking-uri", trained["uri"], "--experiment", "all", "--no-register"]) == 0
    summaries = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(s["method"], s.get("reference")) for s in summaries] == [
        ("entropy", "bj"), ("entropy", "narx"), ("parity", None)], summaries
    assert len({s["run_id"] for s in summaries}) == 3
    assert json.loads((out / "bundles.json").read_text()) == {"default": "parity", "bundles": ["bj", "narx", "parity"]}
    assert json.loads((out / "narx" / "manifest.json").read_text())["reference"] == "narx"
    assert main(["score", "--model", str(out), "--data", str(trained["test"] / "load_alert.parquet"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["summary"]["windows"] >= 5
    assert sum(w["state"] == "load_alert" for w in result["windows"]) / result["summary"]["windows"] >= 0.9
