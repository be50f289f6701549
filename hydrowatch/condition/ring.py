"""A fixed-size ring of rows, allocated once and reused in place: the streaming pools' memory (:class:`Ring`).

Per-window arrays kept in a ``deque`` and each freed ``capacity`` windows later among newer ones leave holes in the
heap that no trim returns (docs/bus.md, the seventh soak); a ring's one array does not.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike


class Ring:
    """The last ``capacity`` rows of shape ``shape``, oldest first in :meth:`rows`.

    Parameters
    ----------
    capacity : int
        Rows kept.
    shape : tuple of int
        Shape of one row (``()`` for scalars).
    dtype : numpy dtype, default float64
        What a row holds (a row added is cast to it).
    """

    def __init__(self, capacity: int, shape: tuple[int, ...] = (), dtype: DTypeLike = np.float64) -> None:
        self._data = np.empty((int(capacity), *shape), dtype=dtype)
        self._next = 0
        self._count = 0

    def __len__(self) -> int:
        return self._count

    @property
    def nbytes(self) -> int:
        """Bytes of the ring's array (held whatever its fill)."""
        return int(self._data.nbytes)

    @property
    def row_shape(self) -> tuple[int, ...]:
        """Shape of one row."""
        return tuple(self._data.shape[1:])

    def add(self, row: ArrayLike) -> None:
        """Keep ``row`` (anything numpy casts to the row shape), dropping the oldest when full."""
        capacity = self._data.shape[0]
        self._data[self._next] = row
        self._next = (self._next + 1) % capacity
        self._count = min(self._count + 1, capacity)

    def rows(self) -> np.ndarray:
        """The rows held, oldest first, shape (len, *row_shape) (a copy)."""
        return self._data[(np.arange(self._count) + self._next - self._count) % self._data.shape[0]]

    def latest(self) -> np.ndarray:
        """The newest row (a copy); IndexError when empty."""
        if not self._count:
            raise IndexError("the ring is empty")
        return self._data[(self._next - 1) % self._data.shape[0]].copy()
