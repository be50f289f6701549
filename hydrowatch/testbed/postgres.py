"""A throwaway PostgreSQL cluster in a temporary folder, for an MLflow tracking server's backend store.

``initdb`` and ``pg_ctl`` (Debian's ``postgresql`` package, any version) make and start a cluster that listens
only on a Unix socket in its own folder, with trust authentication and no fsync: nothing outside this machine's
processes reaches it, and it is gone when the block ends. PostgreSQL refuses to run as root: as root, the cluster
runs as the system user ``postgres`` (``runuser``), which owns its folder.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import TracebackType

DATABASE = "mlflow"


def _bin(name: str) -> str | None:
    """``name`` on PATH, else in the newest ``/usr/lib/postgresql/<version>/bin``."""
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"), key=lambda p: int(Path(p).parts[4]))
    return candidates[-1] if candidates else None


def _run_as() -> str | None:
    """The user to run PostgreSQL as: None (this one) unless root, then ``postgres``."""
    return "postgres" if os.geteuid() == 0 else None


def postgres_unavailable() -> str | None:
    """Why a PostgreSQL backend cannot be had here (None: it can)."""
    missing = [name for name in ("initdb", "pg_ctl") if _bin(name) is None]
    if missing:
        return f"no PostgreSQL server programs ({', '.join(missing)}); install Debian's `postgresql` package"
    if importlib.util.find_spec("psycopg2") is None:
        return "no PostgreSQL driver for MLflow: pip install psycopg2-binary (in hydrowatch's dev extras)"
    user = _run_as()
    if user is not None:
        try:
            pwd.getpwnam(user)
        except KeyError:
            return f"running as root and there is no system user {user!r} to run PostgreSQL as"
        if shutil.which("runuser") is None:
            return "running as root and there is no `runuser` to run PostgreSQL as another user"
    return None


class PostgresCluster:
    """A PostgreSQL cluster for the block's duration; ``uri`` is the SQLAlchemy URI of its ``mlflow`` database.

    Parameters
    ----------
    port : int
        The socket's port number (it names the socket file; nothing listens on TCP).
    """

    def __init__(self, *, port: int = 5432) -> None:
        self.port = port
        self.folder: Path | None = None
        self._started = False

    @property
    def uri(self) -> str:
        """``postgresql+psycopg2://postgres@/mlflow?host=<socket folder>&port=<port>`` (SQLAlchemy 2.1 takes a bare
        ``postgresql://`` to mean psycopg 3)."""
        return f"postgresql+psycopg2://postgres@/{DATABASE}?host={self.folder}&port={self.port}"

    def _run(self, *argv: str) -> None:
        user = _run_as()
        command = [*(["runuser", "-u", user, "--"] if user else []), *argv]
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=120)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(argv[:2])} failed ({done.returncode}): {done.stderr.strip()[-500:]}")

    def __enter__(self) -> PostgresCluster:
        reason = postgres_unavailable()
        if reason:
            raise RuntimeError(reason)
        self.folder = Path(tempfile.mkdtemp(prefix="hydrowatch-pg-"))
        user = _run_as()
        if user is not None:
            entry = pwd.getpwnam(user)
            os.chown(self.folder, entry.pw_uid, entry.pw_gid)
        try:
            data = self.folder / "data"
            self._run(str(_bin("initdb")), "-D", str(data), "-U", "postgres", "-A", "trust", "-E", "UTF8",
                      "--no-sync", "--no-instructions")
            options = (f"-k {self.folder} -p {self.port} -c listen_addresses='' -c fsync=off "
                       "-c synchronous_commit=off -c full_page_writes=off")
            self._run(str(_bin("pg_ctl")), "-D", str(data), "-o", options, "-l", str(self.folder / "postgres.log"),
                      "-w", "-t", "60", "start")
            self._started = True
            createdb = _bin("createdb")
            if createdb is None:
                raise RuntimeError("no createdb beside pg_ctl")
            self._run(createdb, "-h", str(self.folder), "-p", str(self.port), "-U", "postgres", DATABASE)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop the cluster (fast: no checkpoint wait) and remove its folder."""
        if self.folder is None:
            return
        if self._started:
            try:
                self._run(str(_bin("pg_ctl")), "-D", str(self.folder / "data"), "-m", "immediate", "-w", "stop")
            except (RuntimeError, subprocess.TimeoutExpired):
                pass
            self._started = False
        shutil.rmtree(self.folder, ignore_errors=True)
        self.folder = None

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()
