"""The degradation bench's stored window fits (benchmarks/degradation_fits.py): read back, they give the bench the
same figures as the fits it computed; fits of another draw or made by other library code are refused, naming the
file."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import degradation_fits as F  # noqa: E402
from bench_degradation import score_unit  # noqa: E402

HOURS = 0.1  # 6 minutes: paths of 4 minutes from 2 on, seven machines


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    rng = np.random.default_rng(11)
    draws = [F.draw_unit(k, rng, HOURS) for k in range(2)]
    path = F.fits_path(tmp_path_factory.mktemp("fits"), 11, 0, HOURS, "noise")
    fits, read = F.cached_fits(path.parent, 11, 0, draws[0], HOURS, "noise")
    assert not read and path.exists()
    return draws, fits, path


def test_stored_fits_give_the_bench_the_same_figures(stored):
    draws, fits, path = stored
    again, read = F.cached_fits(path.parent, 11, 0, draws[0], HOURS, "noise")
    assert read
    assert again["t"].size == fits["t"].size == 72  # 360 s of 5 s windows
    for machine, (valid, est) in fits["machines"].items():
        np.testing.assert_array_equal(again["machines"][machine][0], valid)
        for field in F.FIELDS:
            for key, x in getattr(est, field).items():
                np.testing.assert_array_equal(getattr(again["machines"][machine][1], field)[key], x)
    want = json.dumps(score_unit(fits, draws[0]), sort_keys=True, default=str)
    assert json.dumps(score_unit(again, draws[0]), sort_keys=True, default=str) == want


def test_fits_of_another_draw_or_other_code_are_refused(stored, monkeypatch):
    draws, _, path = stored
    with pytest.raises(ValueError, match=f"{path.name}.*another unit"):
        F.load_fits(path, draws[1])
    monkeypatch.setattr(F, "fingerprint", lambda: "0" * 64)
    with pytest.raises(ValueError, match=f"{path.name}.*fits otherwise"):
        F.load_fits(path, draws[0])


def test_a_kept_relief_shut_screen_draws_its_units_without_screening_again(tmp_path, monkeypatch):
    # the screen's unit numbers, kept beside the fits by the code that screened: the same draws as the seed's own,
    # no unit simulated; kept by other code (another fingerprint), the screen runs again
    monkeypatch.setattr(F, "fingerprint", lambda: "a" * 64)
    kept = tmp_path / f"seed5_relief_shut_{HOURS:g}h.json"
    kept.write_text(json.dumps({"fingerprint": "a" * 64, "units": [1, 3]}))
    rng = np.random.default_rng(5)
    want = [F.draw_unit(k, rng, HOURS) for k in range(4)]

    def screened(*_):
        raise AssertionError("screened again")

    monkeypatch.setattr(F, "_true_share", screened)
    got = F.relief_shut_units(5, 2, HOURS, folder=tmp_path)
    assert [k for k, _ in got] == [1, 3]
    assert [F._draw_summary(d) for _, d in got] == [F._draw_summary(want[1]), F._draw_summary(want[3])]
    monkeypatch.setattr(F, "fingerprint", lambda: "b" * 64)
    with pytest.raises(AssertionError, match="screened again"):
        F.relief_shut_units(5, 2, HOURS, folder=tmp_path)
