"""The streaming pools' fixed rings (hydrowatch.condition.ring.Ring): the last rows in order, in one array."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.condition.ring import Ring


def test_a_ring_keeps_the_last_rows_oldest_first_in_the_one_array_it_allocated():
    ring = Ring(3, (2,))
    data = ring._data
    assert len(ring) == 0 and ring.rows().shape == (0, 2) and ring.nbytes == 3 * 2 * 8
    with pytest.raises(IndexError, match="empty"):
        ring.latest()
    for k in range(5):
        ring.add([k, -k])
    assert len(ring) == 3
    np.testing.assert_array_equal(ring.rows(), [[2, -2], [3, -3], [4, -4]])
    np.testing.assert_array_equal(ring.latest(), [4, -4])
    assert ring._data is data  # reused in place, nothing allocated per row
    ring.rows()[0] = 99.0  # rows and latest are copies
    ring.latest()[0] = 99.0
    np.testing.assert_array_equal(ring.rows()[:, 0], [2, 3, 4])


def test_a_ring_casts_rows_to_its_dtype():
    flags = Ring(2, (3,), bool)
    flags.add(np.array([1, 0, 2]))
    flags.add([0.0, 0.0, 1.0])
    assert flags.rows().dtype == bool and flags.nbytes == 6
    np.testing.assert_array_equal(flags.rows(), [[True, False, True], [False, False, True]])
    assert int(Ring(4, (), bool).rows().sum()) == 0
