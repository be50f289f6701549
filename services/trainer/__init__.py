"""Trainer service: trains from a recordings folder (e.g. the recorder's) and registers the model.

A thin wrapper over :func:`hydrowatch.training.pipeline.train_each` (``--method``: parity, entropy,
both or all, the default, as ``hydrowatch train``): trains once, or every
``--every`` seconds (the registry alias then moves to each new version, and scorers started with
``--follow-alias`` switch). Files that cannot be read yet (an MCAP the recorder is still writing)
are skipped. SIGINT/SIGTERM stops it between trainings.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from hydrowatch.bus.service import service_main
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger
from hydrowatch.training.options import (
    add_tracking_arguments,
    add_training_arguments,
    settings_list_from_args,
    tracking_names,
)

NAME = "trainer"
HELP = "train from a recordings folder (once or every N seconds) and register the model in MLflow"
log = get_logger("services.trainer")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=Path("recordings"), help="recordings folder (default recordings)")
    parser.add_argument("--out", type=Path, default=Path("models/latest"), help="bundle folder (default models/latest)")
    parser.add_argument("--every", type=float, default=0.0, help="retrain every this many seconds (0: once)")
    add_training_arguments(parser)
    add_tracking_arguments(parser)


def _train_once(args: argparse.Namespace, settings: list, failure: list[DataError]) -> None:
    """One training of every method (runs in a worker thread, :func:`run`); a DataError is handed back, and so is a
    tracking server that cannot be reached once MLflow's own retries (~2 min) are spent, as a DataError: the next
    training registers again."""
    from mlflow.exceptions import MlflowException

    from hydrowatch.training.pipeline import train_each

    experiment, model_name = tracking_names(args)  # the plant's: the trainer trains from sensor recordings
    try:
        for summary in train_each(
                args.data, args.out, settings, tracking=args.tracking_uri, experiment=experiment,
                model_name=model_name, alias=args.alias, skip_unreadable=True,
                check_seconds=args.check_seconds):
            print(json.dumps(summary), flush=True)
    except DataError as exc:
        failure.append(exc)
    except (OSError, MlflowException) as exc:  # requests' connection errors are OSErrors
        failure.append(DataError(f"training not logged or registered in MLflow: {str(exc).splitlines()[0][:300]}"))


def _end_now() -> NoReturn:
    """End the process at once with status 0, its output flushed: the abandoned training thread may be inside compiled
    code (torch, numba), and the interpreter's finalisation then aborts the process ("terminate called without an
    active exception", SIGABRT, seen under `hydrowatch up` with the trainer stopped mid-training)."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Train (repeatedly with ``--every``) until ``stop``; returns 0, or 2 when a single training fails.

    Each training runs in a worker thread, so that a stop request is answered at once even mid-training (tens of
    seconds): the training in progress is then abandoned and the process ends there, status 0 (:func:`_end_now`).
    Nothing is lost by that: the recordings stay, and a training's MLflow run is opened only after it has trained
    (:func:`hydrowatch.training.tracking.log_training`).
    """
    settings = settings_list_from_args(args)
    while not stop.is_set():
        failure: list[DataError] = []
        worker = threading.Thread(target=_train_once, args=(args, settings, failure), name="training", daemon=True)
        worker.start()
        while worker.is_alive() and not stop.wait(0.2):
            pass
        if worker.is_alive():
            event(log, "training abandoned: stop requested", logging.WARNING)
            _end_now()
        if failure:
            if args.every <= 0:
                raise failure[0]
            event(log, "training skipped", logging.WARNING, reason=str(failure[0]))
        if args.every <= 0 or stop.wait(args.every):
            break
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.trainer``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
