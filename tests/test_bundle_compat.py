"""Bundles saved before the health-method interface (issue 13, main at 68a3627) still load, score and stream.

``tests/bundles/main-68a3627`` holds a Box-Jenkins entropy bundle and a parity bundle written by that
version (``train --method all`` on 177.5 s per state of 4 states, seed 0; the NARX bundle is left out, its
torch files being the larger). Their verdicts on a fixed recording were compared with the new code's
outside the test suite (identical); here the layout and the round trip are pinned (a parity bundle saved
again is written in today's layout of the condition features, which changed on main after 68a3627).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.online import Chunk, OnlineScorer
from hydrowatch.training.scoring import score_recording

OLD = Path(__file__).parent / "bundles" / "main-68a3627"
STATES = ["healthy", "load_alert", "motor_leak_alert", "pump_leak_warning"]  # file order (sorted names)


@pytest.mark.parametrize(("key", "method", "rows"), [("bj", "entropy", ["flow", "speed", "torque"]),
                                                     ("parity", "parity", ["load", "motor", "valve"])])
def test_an_old_bundle_loads_scores_streams_and_saves_again(key: str, method: str, rows: list[str],
                                                                     tmp_path: Path) -> None:
    bundle = ModelBundle.load(OLD / key)
    manifest = json.loads((OLD / key / "manifest.json").read_text())
    assert bundle.method == method and bundle.version == manifest["version"] and bundle.states == STATES
    assert bundle.kl_rows == rows and bundle.window == 1000
    (r,) = simulate_states(["load_alert"], seconds=12, seed=5)
    scored = score_recording(bundle, r)
    assert scored["summary"]["windows"] >= 1 and scored["summary"]["model_version"] == manifest["version"]
    scorer = OnlineScorer(bundle)
    verdicts = scorer.update([Chunk("f/m", r.t, {c: r[c] for c in scorer.columns})])
    assert [v.verdict.state for v in verdicts] == [w["state"] for w in scored["windows"]][:len(verdicts)]
    copy = tmp_path / "copy"
    shutil.copytree(OLD / key, tmp_path / "old")
    ModelBundle.load(tmp_path / "old").save(copy)  # saved again in today's layout: the same verdicts
    again = score_recording(ModelBundle.load(copy), r)["windows"]
    assert [w["state"] for w in again] == [w["state"] for w in scored["windows"]]
    if key == "bj":  # nothing of the entropy method's files changed since: the same bytes, the same content hash
        assert json.loads((copy / "manifest.json").read_text())["version"] == manifest["version"]
