"""The bundle as an MLflow model (issue 16, item 5): ``hydrowatch train`` logs it as the run's pyfunc model, the
registered version points at that model, hydrowatch and ``mlflow.pyfunc`` both load it and agree with ``score``; the
accuracy checks are run metrics; versions registered before (the bundle folder as run artifacts) still load."""

from __future__ import annotations

import contextlib
import io
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hydrowatch.cli import main
from hydrowatch.errors import DataError
from hydrowatch.io import write_recording
from hydrowatch.plant.excitation import duty_cycle
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.recording import Recording
from hydrowatch.training.bundle import load_bundle
from hydrowatch.web.browser import Chromium, find_chromium

STATES = ["healthy", "load_alert", "pump_leak_warning", "motor_leak_alert"]


def run_cli(argv: list[str]) -> list[dict]:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(argv) == 0
    return [json.loads(line) for line in buffer.getvalue().splitlines()]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """40 s per state → ``train --method parity --check-seconds 20`` into a tmp SQLite store; two machines on a
    duty cycle of another seed to score."""
    root = tmp_path_factory.mktemp("mlflow_model")
    data, test = root / "data", root / "test"
    duty = list(simulate_states(["load_alert", "motor_leak_alert"], command=duty_cycle(70, seed=21), seed=21))
    for folder, suffix, recordings in ((data, "mcap", simulate_states(STATES, seconds=40, seed=0)),
                                       (test, "parquet", duty)):
        folder.mkdir()
        for r in recordings:
            write_recording(r, folder / f"{r.state}.{suffix}")
    uri = f"sqlite:///{root / 'mlflow.db'}"
    [summary] = run_cli(["train", "--data", str(data), "--out", str(root / "model"), "--method", "parity",
                         "--check-seconds", "20", "--tracking-uri", uri, "--experiment", "test", "--json"])
    import mlflow

    mlflow.set_tracking_uri(uri)
    return {"root": root, "test": test, "duty": duty, "uri": uri, "summary": summary,
            "client": mlflow.MlflowClient(uri, uri)}


def samples(recording: Recording) -> pd.DataFrame:
    """A recording's samples as the model's input: ``t`` and the channels, one row per sample."""
    return pd.DataFrame({"t": recording.t, **recording.channels})


def test_the_run_logs_the_bundle_as_a_model_that_the_registered_version_points_at(trained: dict) -> None:
    client, summary = trained["client"], trained["summary"]
    run = client.get_run(summary["run_id"])
    [output] = run.outputs.model_outputs
    model = client.get_logged_model(output.model_id)
    assert model.source_run_id == run.info.run_id and model.name == run.info.run_name
    assert model.tags["method"] == "parity" and model.params["method"] == "parity"
    assert {m.key for m in model.metrics} >= {"test_accuracy", "accuracy.duty_cycle"}  # shown on the model's page
    version = client.get_model_version_by_alias("hydrowatch", "champion")
    assert summary["model_uri"] == "models:/hydrowatch@champion" and str(version.version) == "1"
    assert version.source == f"models:/{model.model_id}" and version.run_id == run.info.run_id
    assert json.loads(model.tags["mlflow.modelVersions"]) == [{"name": "hydrowatch", "version": "1"}]
    files = {f.path for f in client.list_logged_model_artifacts(model.model_id, "artifacts/bundle")}
    assert "artifacts/bundle/manifest.json" in files
    assert not client.list_artifacts(run.info.run_id, "bundle")  # one copy of the bundle: the model's


def test_the_checks_are_run_metrics(trained: dict) -> None:
    metrics = trained["client"].get_run(trained["summary"]["run_id"]).data.metrics
    checks = trained["summary"]["checks"]
    for command in ("training", "duty_cycle", "narrow_range"):
        assert metrics[f"accuracy.{command}"] == checks[command]
        assert 0.9 <= metrics[f"accuracy.{command}"] <= 1.0, (command, metrics[f"accuracy.{command}"])
        assert metrics[f"windows.{command}"] == 4 * len(STATES)  # 20 s per state: four 5 s windows
        assert 0.5 <= metrics[f"recall_min.{command}"] <= metrics[f"accuracy.{command}"] + 1e-12
    assert metrics["test_accuracy"] == trained["summary"]["test_accuracy"] >= 0.9
    # the experiment's runs-table view shows them as columns (MLflow 3.17 shows no metric until one is chosen)
    experiment = trained["client"].get_experiment_by_name("test")
    view = json.loads(experiment.tags["mlflow.sharedViewState.checks"])
    assert view["selectedColumns"] == ["attributes.`Models`", "metrics.`test_accuracy`", "metrics.`recall_min`",
                                       "metrics.`accuracy.training`", "metrics.`accuracy.duty_cycle`",
                                       "metrics.`accuracy.narrow_range`", "metrics.`train_seconds`"]
    assert trained["summary"]["runs_url"] == (f"http://127.0.0.1:5000/#/experiments/{experiment.experiment_id}/runs"
                                              "?workflowType=machine_learning&viewStateShareKey=checks")
    assert metrics["recall_min"] == min(trained["summary"]["per_class_recall"].values())
    assert metrics["train_seconds"] > 0


def test_registry_model_scores_through_hydrowatch_and_pyfunc_alike(trained: dict,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    import mlflow

    capsys.readouterr()
    assert main(["score", "--model", "models:/hydrowatch@champion", "--tracking-uri", trained["uri"],
                 "--data", str(trained["test"]), "--json"]) == 0
    scored = {Path(r["source"]).stem: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert {k: r["summary"]["model_version"] for k, r in scored.items()} == {
        "load_alert": "hydrowatch/v1", "motor_leak_alert": "hydrowatch/v1"}
    assert all(r["summary"]["accuracy"] >= 0.9 for r in scored.values()), scored

    model = mlflow.pyfunc.load_model("models:/hydrowatch@champion")
    assert model.metadata.get_params_schema().params[0].default == 12  # parity pools 12 windows, as `score`
    both = pd.concat([samples(r).assign(machine=r.state) for r in trained["duty"]], ignore_index=True)
    windows = model.predict(both)
    for r in trained["duty"]:
        expected = scored[r.state]["windows"]
        got = windows[windows["machine"] == r.state]
        assert len(got) == len(expected) == 14
        assert got["state"].tolist() == [w["state"] for w in expected]
        assert got["start_s"].tolist() == [w["start_s"] for w in expected]
        np.testing.assert_allclose(got["probability"], [w["probability"] for w in expected], rtol=1e-12)
    alone = model.predict(samples(trained["duty"][0]), params={"smoothing": 1})
    assert set(alone["machine"]) == {""} and len(alone) == 14 and alone["state"].eq("load_alert").mean() >= 0.9


def test_model_input_without_a_sensor_or_with_a_gap_is_refused_naming_it(trained: dict) -> None:
    import mlflow
    from mlflow.exceptions import MlflowException

    model = mlflow.pyfunc.load_model("models:/hydrowatch@champion")
    with pytest.raises(MlflowException, match="torque"):
        model.predict(samples(trained["duty"][0]).drop(columns=["torque"]))
    gap = samples(trained["duty"][0]).assign(machine="m7")
    gap.loc[100, "flow"] = np.nan
    with pytest.raises(DataError, match=r"model input machine m7: column 'flow' must have no NaN"):
        model.predict(gap)


def test_a_version_registered_before_as_a_bundle_folder_still_loads(trained: dict) -> None:
    """Before issue 16 a version's source was the run's ``bundle/`` artifacts folder."""
    import mlflow

    client = trained["client"]
    experiment = client.get_experiment_by_name("test").experiment_id
    with mlflow.start_run(experiment_id=experiment) as run:
        mlflow.log_artifacts(str(trained["root"] / "model"), "bundle")
    old = client.create_model_version("hydrowatch", source=f"{run.info.artifact_uri}/bundle", run_id=run.info.run_id)
    bundle = load_bundle(f"models:/hydrowatch/{old.version}", trained["uri"])
    assert bundle.version == f"hydrowatch/v{old.version}" and bundle.method == "parity"
    current = load_bundle("models:/hydrowatch@champion", trained["uri"])
    assert current.version == "hydrowatch/v1" and current.states == bundle.states


@pytest.fixture(scope="module")
def mlflow_server(trained: dict) -> Iterator[str]:
    """``mlflow server`` on the test's store, on loopback, artifacts of new experiments proxied into the test's
    folder; its address."""
    import subprocess
    import sys
    import urllib.request

    from hydrowatch.bus import free_port

    address = f"http://127.0.0.1:{free_port()}"
    server = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--backend-store-uri", trained["uri"],
                               "--artifacts-destination", str(trained["root"] / "served"), "--host", "127.0.0.1",
                               "--port", address.rsplit(":", 1)[1], "--workers", "1"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                with urllib.request.urlopen(f"{address}/health", timeout=2) as answer:
                    if answer.status == 200:
                        break
            except OSError:
                if server.poll() is not None or time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        yield address
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_over_http_the_json_stays_clean_and_the_registered_model_loads(trained: dict, mlflow_server: str,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Through ``mlflow server`` (artifacts proxied, ``mlflow-artifacts:/``): MLflow's "View run" lines do not mix
    into the JSON on stdout, and the registered version's model downloads and scores."""
    capsys.readouterr()
    assert main(["train", "--data", str(trained["root"] / "data"), "--out", str(trained["root"] / "http"),
                 "--method", "parity", "--tracking-uri", mlflow_server, "--experiment", "http", "--json"]) == 0
    [summary] = [json.loads(line) for line in capsys.readouterr().out.splitlines()]  # only JSON on stdout
    version = summary["registered_version"]
    assert summary["runs_url"].startswith(f"{mlflow_server}/#/experiments/")
    assert main(["score", "--model", f"models:/hydrowatch/{version}", "--tracking-uri", mlflow_server,
                 "--data", str(trained["test"] / "load_alert.parquet"), "--json"]) == 0
    scored = json.loads(capsys.readouterr().out)
    assert scored["summary"]["model_version"] == f"hydrowatch/v{version}" and scored["summary"]["accuracy"] >= 0.9
    source = trained["client"].get_model_version("hydrowatch", version).source
    assert source.startswith("models:/m-")


@pytest.mark.skipif(find_chromium() is None, reason="no Chromium installed (apt-get install chromium; `make test` "
                                                     "does it where apt is available)")
def test_mlflow_ui_shows_the_runs_model_and_checks_in_the_training_view(trained: dict, mlflow_server: str) -> None:
    """The address ``train`` prints opens MLflow's own UI in the model-training view, with the registered model and
    the checks as columns of the runs table (MLflow 3.17 in headless Chromium)."""
    from hydrowatch.training.tracking import runs_table_url

    experiment = trained["client"].get_experiment_by_name("test").experiment_id
    with Chromium(width=1600, height=700) as browser:
        browser.navigate(runs_table_url(mlflow_server, experiment))
        headers = "Array.from(document.querySelectorAll('[role=columnheader]')).map(e => e.innerText.trim())"
        seen = browser.wait_for(f"(h => h.includes('accuracy.duty_cycle') && h)({headers})", timeout=60)
        assert {"Models", "accuracy.training", "accuracy.narrow_range", "test_accuracy", "recall_min"} <= set(seen)
        grid = browser.wait_for("(t => t.includes('hydrowatch') && t)(document.querySelector('[role=grid]')"
                                "?.innerText || '')", timeout=30)
        run = trained["client"].get_run(trained["summary"]["run_id"])
        assert run.info.run_name in grid and "v1" in grid  # the run, its registered model and version
        page = browser.evaluate("document.body.innerText")
        assert "Sessions" not in page and "Judges" not in page  # the GenAI view's navigation is not there
