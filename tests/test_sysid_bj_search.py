"""Automatic order search by the study's rules, and ``hydrowatch identify``."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from hydrowatch.cli import main
from hydrowatch.sysid import search_orders
from hydrowatch.sysid.pem import filtered_white_noise, simulate_box_jenkins

TRUE = {"nb": 2, "nf": 2, "nc": 1, "nd": 1, "delay": 2}


def data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = filtered_white_noise(n, rng)
    y = simulate_box_jenkins([1.0, 0.5], [-1.2, 0.5], [0.5], [-0.8], 2, u, 0.5 * rng.standard_normal(n))
    return 1.0 + u, 20.0 + y


@pytest.mark.parametrize(
    "start",
    [None, {"nb": 1, "nf": 1, "nc": 0, "nd": 0, "delay": 2}, {"nb": 3, "nf": 3, "nc": 2, "nd": 2, "delay": 1}],
    ids=["from-gpac", "from-below", "from-above"],
)
def test_search_finds_the_true_orders(start) -> None:
    for seed in range(2):
        result = search_orders(*data(3000, seed), start)
        assert result.orders == TRUE, result.history
        assert result.history[0]["action"] == "start"


def test_identify_command_prints_the_contract_json(tmp_path, capsys) -> None:
    u, y = data(3000, 5)
    t = np.arange(u.size) / 200.0
    path = tmp_path / "healthy.parquet"
    columns = {"t": t, "voltage": u, "flow": 0.1 * y, "speed": y, "torque": 0.01 * y}
    pq.write_table(pa.table(columns), path)
    code = main(["identify", "--data", str(path), "--output", "speed", "--model", "bj", "--orders", "2,2,1,1",
                 "--delay", "2", "--json", "--save", str(tmp_path / "bj.json")])  # fmt: skip
    document = json.loads(capsys.readouterr().out)
    assert code == 0
    assert document["orders"] == {"nb": 2, "nf": 2, "nc": 1, "nd": 1} and document["delay"] == 2
    assert document["parameters"]["f1"]["ci95"][0] < -1.2 < document["parameters"]["f1"]["ci95"][1]
    assert 0 < document["nrmse_one_step"] < 1 and document["validation"]["Q_dof"] == 33
    assert (tmp_path / "bj.json").exists()
    assert main(["identify", "--data", str(path), "--output", "speed", "--auto", "--json"]) == 0
    auto = json.loads(capsys.readouterr().out)
    assert auto["orders"] == {k: TRUE[k] for k in ("nb", "nf", "nc", "nd")} and auto["delay"] == 2
    assert auto["preliminary"]["delay"] == 2 and auto["search"]
    assert main(["identify", "--data", str(path), "--output", "pressure"]) == 2
    assert "output column must be one of" in capsys.readouterr().err
    assert main(["identify", "--data", str(path), "--output", "speed", "--orders", "2,2"]) == 2
    assert "--orders must be 4" in capsys.readouterr().err
