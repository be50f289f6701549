import numpy as np
import pytest

from hydrowatch.errors import DataError
from hydrowatch.recording import Recording


def test_recording_checks_shapes_and_slices():
    t = np.arange(10) / 200.0
    rec = Recording(t, {"voltage": np.ones(10), "flow": np.zeros(10)}, {"state": "healthy"})
    assert len(rec) == 10 and rec.state == "healthy"
    part = rec.slice(2, 5)
    assert len(part) == 3 and part["t"][0] == pytest.approx(0.01)
    with pytest.raises(DataError, match="channel 'flow' must have shape"):
        Recording(t, {"flow": np.zeros(9)})
    with pytest.raises(KeyError, match="no channel 'speed'"):
        rec["speed"]


def test_slice_keeps_per_sample_labels_aligned():
    t = np.arange(10) / 200.0
    labels = np.array(["healthy"] * 6 + ["load_warning"] * 4, dtype=object)
    rec = Recording(t, {"voltage": np.ones(10)}, {"state": None, "labels": labels})
    part = rec.slice(4, 8)
    assert part.meta["labels"].tolist() == ["healthy", "healthy", "load_warning", "load_warning"]
    assert len(rec.meta["labels"]) == 10
