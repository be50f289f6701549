"""Labelled recordings for training and scoring: find the files, read them, group them by health state.

Any format :func:`hydrowatch.io.read_recording` reads (MCAP, Parquet, CSV) is accepted. A file's
label is its constant ``state`` (metadata or column); a file whose labels change from row to row
is cut into runs of one label each. The health states are whatever the data carries; ``healthy``
must be among them (it trains the reference models).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from hydrowatch.errors import DataError
from hydrowatch.io import read_recording
from hydrowatch.io.mcap_io import mcap_finished
from hydrowatch.io.recordings import SUFFIXES
from hydrowatch.log import event, get_logger
from hydrowatch.methods.base import HEALTHY, ordered_states
from hydrowatch.recording import Recording

__all__ = ["HEALTHY", "label_runs", "ordered_states", "read_labelled", "recording_files"]
_log = get_logger(__name__)


def recording_files(path: str | Path) -> list[Path]:
    """The recording files at ``path``: the file itself, or every .mcap/.parquet/.csv in the folder and its subfolders
    (sorted; the recorder writes ``<out>/<fleet>/<machine>/*.mcap``)."""
    p = Path(path)
    if p.is_file():
        return [p]
    if not p.is_dir():
        raise DataError(f"--data must be a recording file or a folder of them. Got {str(p)!r}, which does not exist.")
    files = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix in SUFFIXES)
    if not files:
        raise DataError(f"folder must hold recordings ({', '.join(SUFFIXES)}). Got none.", str(p))
    return files


def label_runs(recording: Recording) -> list[Recording]:
    """The recording cut into runs of one health label each (one run when the label is constant)."""
    labels = recording.meta.get("labels")
    if labels is None:
        return [recording]
    labels = np.asarray(labels).astype(str)
    cuts = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    runs = []
    for start, stop in zip(np.concatenate(([0], cuts)), np.concatenate((cuts, [labels.size]))):
        part = recording.slice(int(start), int(stop))
        part.meta.pop("labels", None)
        part.meta["state"] = str(labels[start])
        runs.append(part)
    return runs


def read_labelled(path: str | Path, *, skip_unreadable: bool = False) -> dict[str, list[Recording]]:
    """Every labelled run under ``path``, grouped by health state (file order kept).

    ``skip_unreadable``: leave out files that cannot be read instead of failing: an MCAP file without its closing
    bytes (a recorder is still writing it; logged at debug level only, it is expected) unread, others logged.

    Raises
    ------
    DataError
        When a file has no label or no recording is labelled ``healthy``.
    """
    grouped: dict[str, list[Recording]] = {}
    for file in recording_files(path):
        if skip_unreadable and file.suffix == ".mcap" and not mcap_finished(file):
            # a recorder is most likely still writing it: expected, so neither read nor warned about
            event(_log, "unfinished recording skipped", logging.DEBUG, file=str(file))
            continue
        try:
            recording = read_recording(file)
        except DataError as exc:
            if not skip_unreadable:
                raise
            event(_log, "recording skipped", logging.WARNING, file=str(file), reason=str(exc))
            continue
        if recording.state is None and recording.meta.get("labels") is None:
            raise DataError(
                "training recordings must carry a health label (metadata or a 'state' column). Got none. "
                "Label it with `hydrowatch import FILE --out FILE.mcap --label STATE`.",
                str(file),
            )
        for run in label_runs(recording):
            grouped.setdefault(str(run.state), []).append(run)
    if HEALTHY not in grouped:
        raise DataError(
            f"training data must include the '{HEALTHY}' state (it trains the reference models). "
            f"Got states {sorted(grouped)}.",
            str(path),
        )
    return grouped
