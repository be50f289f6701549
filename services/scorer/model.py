"""The scorer's model: the bundle in use, the registry alias it follows, and the rig it serves.

:class:`_Model` holds the bundle and, with ``--follow-alias``, a thread that looks at the alias and loads the version
it moved to; :func:`served_rig` says which rig the scorer serves and :func:`_first_model` loads the model to start
with (waiting for an alias not registered yet). Every model must serve that rig (:mod:`hydrowatch.training.served`).
The scoring loop is :mod:`services.scorer`.
"""

from __future__ import annotations

import argparse
import logging
import threading
from typing import TYPE_CHECKING

from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger
from hydrowatch.rig.plant import PLANT_RIG
from hydrowatch.training.options import default_model_uri

if TYPE_CHECKING:  # the model code (torch) is imported when the service runs, not when the CLI parses
    from hydrowatch.rig import RigDescription
    from hydrowatch.training.bundle import ModelBundle

log = get_logger("services.scorer")

REGISTRY_ENV = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_TIMEOUT": "10"}
"""MLflow client defaults in the scorer (the environment wins): a registry look-up fails within ~20 s when the server is
down instead of retrying for minutes (MLflow's 7 retries with doubling back-off), so that the alias is looked at
again soon after the server returns."""


class _Model:
    """The bundle in use and, for a followed registry alias, a thread that looks at the alias.

    The thread (:meth:`follow`) resolves the alias every ``--follow-alias`` seconds and, when it moved, loads the new
    version; the scoring loop takes it at its next turn (:meth:`moved`). The loop never waits on MLflow: while the
    server cannot be reached (down, restarting) the thread logs it once, keeps the model in use, and tries again.
    Every model must serve ``served`` (None: the first model's rig; :mod:`hydrowatch.training.served`): the first is
    refused with a DataError, a followed version is logged and skipped (:meth:`take`).
    """

    def __init__(self, args: argparse.Namespace, served: RigDescription | None = None) -> None:
        from hydrowatch.training.bundle import load_bundle
        from hydrowatch.training.served import bundle_rig, check_served

        self.args = args
        self.bundle: ModelBundle = load_bundle(args.model, args.tracking_uri)
        self.served: RigDescription = served if served is not None else bundle_rig(self.bundle)
        check_served(self.bundle, self.served, str(args.model))
        self._loaded = self.bundle.version
        self._refused: set[str] = set()
        self._next: ModelBundle | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    @property
    def following(self) -> bool:
        return self.args.follow_alias > 0 and "@" in str(self.args.model)

    def follow(self, stop: threading.Event) -> None:
        """Start following the alias until ``stop`` (nothing without ``--follow-alias`` or an alias)."""
        if self.following:
            self._thread = threading.Thread(target=self._follow, args=(stop,), name="follow-alias", daemon=True)
            self._thread.start()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=30)

    def moved(self) -> bool:
        """True when the followed alias moved and its new version is now :attr:`bundle`."""
        with self._lock:
            found, self._next = self._next, None
        if found is None:
            return False
        self.bundle = found
        event(log, "model switched", model=self.args.model, version=found.version)
        return True

    def _follow(self, stop: threading.Event) -> None:
        from hydrowatch.training.bundle import load_bundle
        from hydrowatch.training.tracking import parse_model_uri, resolve_version

        a, name, down = self.args, parse_model_uri(self.args.model)[0], False
        while not stop.wait(a.follow_alias):
            try:
                version, _ = resolve_version(a.model, a.tracking_uri)
                current = f"{name}/v{version}"
                found = None if current == self._loaded or current in self._refused else load_bundle(
                    a.model, a.tracking_uri)
            except Exception as exc:  # noqa: BLE001 - any failure to reach or read the registry: keep scoring
                if not down:
                    event(log, "registry unreachable; scoring on with the model in use", logging.WARNING,
                          model=a.model, version=self._loaded, reason=str(exc).split("\n")[0][:300])
                down = True
                continue
            if down:
                event(log, "registry reachable again", model=a.model, version=self._loaded)
                down = False
            if found is not None:
                self.take(found)

    def take(self, found: ModelBundle) -> bool:
        """Hand ``found`` (the followed alias's new version) to the scoring loop, or refuse it when it cannot serve
        the rig (logged once per version; the model in use stays); returns whether it was taken."""
        from hydrowatch.training.served import check_served

        try:
            check_served(found, self.served, str(self.args.model))
        except DataError as exc:
            self._refused.add(found.version)
            event(log, "model refused; scoring on with the model in use", logging.WARNING, model=self.args.model,
                  refused=found.version, version=self._loaded, reason=str(exc))
            return False
        with self._lock:
            self._next, self._loaded = found, found.version
        return True


def served_rig(args: argparse.Namespace) -> RigDescription | None:
    """The rig the scorer serves: ``--rig``'s, the plant's when neither ``--rig`` nor ``--model`` is given, else None
    (the first model's rig); fills in ``args.model`` left out with the served rig's registered model
    (:func:`~hydrowatch.training.options.default_model_uri`)."""
    from hydrowatch.rig.plant import any_rig

    served = any_rig(args.rig) if args.rig is not None else any_rig(PLANT_RIG) if args.model is None else None
    if args.model is None:
        args.model = default_model_uri(served.name if served is not None else PLANT_RIG)
    return served


def _first_model(args: argparse.Namespace, stop: threading.Event) -> _Model | None:
    """The model to start with, refused when made for another rig than the one served (:func:`served_rig`). A
    registry alias followed with ``--follow-alias`` that does not exist yet (a trainer
    started beside the scorer has not registered its first model) or cannot be read (the server is not up) is looked
    for again every ``--follow-alias`` seconds, logged once; None when ``stop`` comes first. Anything else that cannot
    be loaded raises."""
    served = served_rig(args)
    waiting = args.follow_alias > 0 and str(args.model).startswith("models:/")
    logged = False
    unreachable: tuple[type[Exception], ...] = (DataError,)
    if waiting:  # a server not up yet: MLflow's own errors, or the network's (requests' are OSErrors)
        from mlflow.exceptions import MlflowException

        unreachable = (DataError, OSError, MlflowException)
    while True:
        try:
            return _Model(args, served)
        except unreachable as exc:
            if not waiting:
                raise
            if not logged:
                event(log, "waiting for the model", logging.WARNING, model=args.model, reason=str(exc))
                logged = True
        if stop.wait(args.follow_alias):
            return None
