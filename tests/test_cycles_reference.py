"""The study's method on cycles of a rig without a command: the reference model recovers a known relation, the
Gaussian relative entropy has its closed-form values, and ``train --rig`` picks it where a fault changes how two
channels relate while every channel's own statistics stay the same."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.cli import main
from hydrowatch.cycles import ComponentClassifier, ordered_split
from hydrowatch.cycles.reference import CycleReferenceEntropy, gaussian_relative_entropy

SEAL = """name = "seal-rig"
[window]
kind = "cycle"
length_s = 30.0
grid_hz = 1.0
[layout]
kind = "wide"
[channels.X]
unit = "bar"
role = "sensor"
rate_hz = 1.0
source = "X.txt"
[channels.Y]
unit = "bar"
role = "sensor"
rate_hz = 1.0
source = "Y.txt"
[labels]
source = "labels.txt"
[labels.seal]
column = 0
values = [0, 1]
healthy = 0
names = { "0" = "ok", "1" = "worn" }
"""


def seal_cycles(worn: np.ndarray, seed: int) -> np.ndarray:
    """Cycles of 30 s: X = 10 bar + N(0, 1) each second; Y = 5 bar + (X - 10) while the seal is ok and 5 - (X - 10)
    when worn, + N(0, 0.2): each channel's own distribution is the same in both states, their relation is not."""
    rng = np.random.default_rng(seed)
    x = 10.0 + rng.normal(0, 1, (worn.size, 30))
    y = 5.0 + np.where(worn[:, None], -1.0, 1.0) * (x - 10.0) + rng.normal(0, 0.2, x.shape)
    return np.stack([x, y], axis=1)


def test_the_gaussian_relative_entropy_has_its_closed_form_values() -> None:
    d = gaussian_relative_entropy(np.array([0.0, 1.0, 0.0]), np.array([1.0, 1.0, 2.0]), np.zeros(3), np.ones(3))
    np.testing.assert_allclose(d, [0.0, 0.5, np.log(0.5) + 2.0 - 0.5])


def test_the_reference_model_recovers_the_healthy_relation_and_separates_a_changed_one() -> None:
    worn = np.tile([False, True], 60)
    values = seal_cycles(worn, seed=0)
    labels = np.where(worn, "worn", "ok")
    model = CycleReferenceEntropy(healthy="ok", sensors=[1]).fit(values, labels)
    slope = model.coefficients_[0, 0] * model.scale_[1] / model.scale_[0]  # bar of Y per bar of X
    assert slope == pytest.approx(1.0, abs=0.03)
    errors = model.errors(values)[:, 0, :] * model.scale_[1]  # bar
    assert errors[~worn].std() == pytest.approx(0.2, rel=0.1) and errors[worn].std() > 1.5
    train, test = ordered_split(labels)
    for features, least, most in (("entropy", 1.0, 1.0), ("statistics", 0.0, 0.8)):
        fitted = ComponentClassifier(features=features, phases=5, channels=[1] if features == "entropy" else None,
                                     healthy="ok").fit(values[train], labels[train])
        accuracy = np.mean(fitted.predict(values[test]) == labels[test])
        assert least <= accuracy <= most, (features, accuracy)


def test_train_on_a_rig_picks_the_study_method_where_only_the_relation_changes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "seal.toml").write_text(SEAL, encoding="utf-8")
    folder = tmp_path / "data"
    folder.mkdir()
    worn = np.tile([False, False, True], 40)
    values = seal_cycles(worn, seed=1)
    for c, name in enumerate(("X.txt", "Y.txt")):
        (folder / name).write_text("".join("\t".join(f"{v:.4f}" for v in row) + "\n" for row in values[:, c, :]))
    (folder / "labels.txt").write_text("".join(("1" if w else "0") + "\n" for w in worn))
    code = main(["train", "--rig", str(tmp_path / "seal.toml"), "--data", str(folder), "--out", str(tmp_path / "m"),
                 "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}", "--no-register", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["components"]["seal"]["features"] == "entropy"
    figures = summary["components"]["seal"]  # honest split: 36 test cycles named right or read unknown, never wrong
    assert figures["accuracy"] >= 0.94 and figures["accuracy"] + figures["unknown"] == pytest.approx(1.0)
    evaluation = json.loads((tmp_path / "m" / "manifest.json").read_text())
    assert evaluation["features"] == {"seal": "entropy"}
    assert main(["score", "--model", str(tmp_path / "m"), "--data", str(folder), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["summary"]["accuracy"]["seal"] >= 0.95
