"""Import of the wide per-cycle layout (the UCI hydraulic rig's): one text file per channel.

Each file holds one row per cycle (in recording order) and ``length_s * rate_hz`` columns, one per
sample, separated by the description's delimiter. Files are joined by cycle (row ``i`` of every
file is cycle ``i``), resampled onto the window grid by block means (:func:`block_means`) and scaled
(``scale * raw + offset``). Labels per cycle come from the description's label file.

Refused, with file, row and column (both counted from 0): a missing file, a ragged row, a
non-numeric or non-finite cell, files with different numbers of cycles, labels outside the
declared values.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrowatch.errors import DataError
from hydrowatch.rig.description import Label, LabelValue, RigDescription, builtin_rig, data_root


@dataclass(frozen=True)
class Cycles:
    """The cycles of a rig, every channel on the window grid.

    Attributes
    ----------
    values : ndarray, shape (n_cycles, n_channels, n_samples)
        Channel values in the channels' units, on the grid of ``window.grid_hz``.
    channels : tuple of str
        Channel names, in the order of axis 1.
    labels : dict of str to ndarray, shape (n_cycles,)
        Each label's value per cycle (float for numeric labels, str otherwise).
    grid_hz : float
        Sample rate of axis 2, Hz.
    source : str
        The folder the cycles were read from.
    """

    values: np.ndarray
    channels: tuple[str, ...]
    labels: dict[str, np.ndarray]
    grid_hz: float
    source: str

    def __len__(self) -> int:
        return int(self.values.shape[0])

    def channel(self, name: str) -> np.ndarray:
        """One channel's values, shape (n_cycles, n_samples)."""
        if name not in self.channels:
            raise KeyError(f"channel must be one of {list(self.channels)}. Got {name!r}.")
        return self.values[:, self.channels.index(name), :]


def _locate_bad_cell(rows: list[list[str]], source: str) -> DataError:
    for r, cells in enumerate(rows):
        for c, cell in enumerate(cells):
            try:
                value = float(cell)
            except ValueError:
                return DataError(f"row {r}, column {c} must be a number. Got {cell!r}.", source)
            if not np.isfinite(value):
                return DataError(f"row {r}, column {c} must be finite. Got {cell!r}.", source)
    return DataError("every cell must be a finite number.", source)  # not reached: the caller saw one


def read_matrix(path: str | Path, columns: int | None = None, delimiter: str = "\t") -> np.ndarray:
    """Read a delimited numeric matrix, refusing ragged rows and non-numeric or non-finite cells.

    Parameters
    ----------
    path : path
        Text file, one row per line (blank lines at the end are ignored).
    columns : int, optional
        Number of columns every row must have; default: the first row's.
    delimiter : str, default tab

    Returns
    -------
    ndarray, shape (n_rows, columns), float64
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError(
            "file must exist. It does not; check the data folder and the description's 'source' keys.", source
        ) from None
    lines = text.rstrip("\n\r ").splitlines()
    if not lines or not lines[0].strip():
        raise DataError("file must hold at least one row. It is empty.", source)
    rows = [line.rstrip("\r").split(delimiter) for line in lines]
    expected = len(rows[0]) if columns is None else columns
    for r, cells in enumerate(rows):
        if len(cells) != expected:
            raise DataError(f"row {r} must have {expected} columns. Got {len(cells)}.", source)
    try:
        matrix = np.array(rows, dtype=np.float64)
    except ValueError:
        raise _locate_bad_cell(rows, source) from None
    if not np.isfinite(matrix).all():
        raise _locate_bad_cell(rows, source)
    return matrix


def block_means(matrix: np.ndarray, rate_hz: float, grid_hz: float) -> np.ndarray:
    """Resample rows of samples at ``rate_hz`` onto ``grid_hz`` by block means.

    Each grid value is the mean of the ``rate_hz / grid_hz`` consecutive samples of its
    ``1 / grid_hz`` s interval (how the UCI copy's 1 Hz pressures were made from 100 Hz). The
    ratio must be a whole number ≥ 1 (the description's validation ensures it).

    Parameters
    ----------
    matrix : ndarray, shape (n_rows, n_samples)
    rate_hz, grid_hz : float
        Sample rate of ``matrix`` and of the result, Hz.

    Returns
    -------
    ndarray, shape (n_rows, n_samples * grid_hz / rate_hz)
    """
    factor = round(rate_hz / grid_hz)
    if factor < 1 or abs(factor - rate_hz / grid_hz) > 1e-9 * factor:
        raise DataError(f"rate_hz / grid_hz must be a whole number >= 1. Got {rate_hz} / {grid_hz}.")
    rows, n = matrix.shape
    if n % factor:
        raise DataError(f"samples per row must be a multiple of {factor} to average in blocks. Got {n}.")
    return matrix.reshape(rows, n // factor, factor).mean(axis=2)


def _label_column(matrix: np.ndarray, label: Label, source: str) -> np.ndarray:
    column = matrix[:, label.column]
    allowed = np.asarray(label.values, dtype=np.float64)
    bad = np.flatnonzero(~np.isin(column, allowed))
    if bad.size:
        r = int(bad[0])
        raise DataError(
            f"row {r}, column {label.column} ({label.name}) must be one of {list(label.values)}. "
            f"Got {column[r]:g}. Declare the value in the description or fix the file.",
            source,
        )
    return column


def read_labels(folder: str | Path, rig: RigDescription) -> dict[str, np.ndarray]:
    """Read the per-cycle labels of a wide-layout rig from its label file, values checked."""
    if rig.label_source is None:
        return {}
    path = Path(folder) / rig.label_source
    if any(isinstance(label.values[0], str) for label in rig.labels):
        raise DataError("a label file of the wide layout must hold numeric labels. Declare numeric values.", str(path))
    widest = max(label.column or 0 for label in rig.labels) + 1
    matrix = read_matrix(path, None, rig.delimiter)
    if matrix.shape[1] < widest:
        raise DataError(
            f"row 0 must have at least {widest} columns (the labels' columns). Got {matrix.shape[1]}.", str(path)
        )
    return {label.name: _label_column(matrix, label, str(path)) for label in rig.labels}


def read_cycles(folder: str | Path, rig: RigDescription) -> Cycles:
    """Read every channel and the labels of a wide-layout rig from ``folder`` and join them by cycle."""
    if rig.layout != "wide":
        raise DataError(
            f"layout must be 'wide' to read per-cycle matrices. Got {rig.layout!r} for rig {rig.name!r}.", str(folder)
        )
    folder = Path(folder)
    first: tuple[str, int] | None = None
    values = []
    for channel in rig.channels:
        sampling = rig.sampling[channel.name]
        path = folder / sampling.source
        matrix = read_matrix(path, round(rig.window.length_s * sampling.rate_hz), rig.delimiter)
        if first is None:
            first = (sampling.source, matrix.shape[0])
        elif matrix.shape[0] != first[1]:
            raise DataError(
                f"file must hold one row per cycle, as many as {first[0]} ({first[1]}). Got {matrix.shape[0]} rows.",
                str(path),
            )
        values.append(sampling.scale * block_means(matrix, sampling.rate_hz, rig.window.grid_hz) + sampling.offset)
    labels = read_labels(folder, rig)
    assert first is not None  # a ChannelSet has at least one channel
    for name, column in labels.items():
        if column.shape[0] != first[1]:
            raise DataError(
                f"label file must hold one row per cycle, as many as {first[0]} ({first[1]}). "
                f"Got {column.shape[0]} rows (label {name!r}).",
                str(folder / str(rig.label_source)),
            )
    return Cycles(np.stack(values, axis=1), rig.channels.names, labels, rig.window.grid_hz, str(folder))


def healthy_mask(cycles: Cycles, rig: RigDescription) -> np.ndarray:
    """Cycles whose every component label is the healthy value, shape (n_cycles,) bool."""
    mask = np.ones(len(cycles), dtype=bool)
    for name in rig.components:
        healthy: LabelValue = rig.label(name).healthy
        mask &= cycles.labels[name] == healthy
    return mask


def shared_cycles(name: str) -> tuple[RigDescription, Cycles] | None:
    """A shipped rig's description and cycles from the shared data folder, or None when it is absent.

    The data is read from ``data_root() / name`` (``$HYDROWATCH_DATA/<name>`` or ``../shared/data/<name>``);
    "absent" means its label file (or, without one, the first channel's file) is not there.
    """
    rig = builtin_rig(name)
    folder = data_root() / name
    marker = rig.label_source or rig.sampling[rig.channels.names[0]].source
    return (rig, read_cycles(folder, rig)) if (folder / marker).is_file() else None
