"""Hosts for a deployment on one machine: each a network namespace joined to the others by a virtual link, or
all on loopback.

With namespaces, every host is ``ip netns`` namespace ``hw<tag>-<name>`` with one veth link (``eth0``,
``10.218.<net>.<i>/24``) on a bridge in the starting namespace, which holds ``.1``: this process reaches every host
and every host reaches every other, as machines on one switch, and nothing else (each namespace has only its link
and its own loopback). Requires root and ``ip`` (iproute2); :func:`namespaces_unavailable` says why not.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

SUBNET = "10.218"
"""First two octets of the hosts' addresses (a /24 per network, picked from the process id)."""


def _ip(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *argv], capture_output=True, text=True, check=False)


def namespaces_unavailable() -> str | None:
    """Why hosts cannot be network namespaces here (None: they can)."""
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2) on this machine"
    if os.geteuid() != 0:
        return f"network namespaces need root; running as uid {os.geteuid()}"
    probe = f"hw{os.getpid()}-probe"
    added = _ip("netns", "add", probe)
    if added.returncode != 0:
        return f"`ip netns add` is not permitted here: {added.stderr.strip()}"
    _ip("netns", "del", probe)
    bridge = f"hw{os.getpid() % 100000}probe"
    added = _ip("link", "add", bridge, "type", "bridge")
    if added.returncode != 0:
        return f"`ip link add type bridge` is not permitted here: {added.stderr.strip()}"
    _ip("link", "del", bridge)
    return None


@dataclass(frozen=True)
class Host:
    """A host: where its processes run and the address others reach them at.

    Parameters
    ----------
    name : str
    address : str
        IPv4 address of the host on the network (``127.0.0.1`` on loopback).
    netns : str or None
        Its network namespace (None: this process's own, i.e. loopback).
    """

    name: str
    address: str
    netns: str | None = None

    def argv(self, argv: Sequence[str]) -> list[str]:
        """``argv`` run on this host (``ip netns exec`` execs the command: the process id stays the same)."""
        return ["ip", "netns", "exec", self.netns, *argv] if self.netns else list(argv)

    def popen(self, argv: Sequence[str], log: Path, env: Mapping[str, str] | None = None) -> subprocess.Popen:
        """Start ``argv`` on this host in a process group of its own (so that a kill reaches its children), standard
        output and error appended to ``log``."""
        with log.open("ab") as out:
            return subprocess.Popen(self.argv(argv), stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                    env={**os.environ, **(env or {})})


class Network:
    """Hosts named ``names``, in namespaces (``namespaces=True``) or on loopback; a context manager that removes
    every namespace, link and the bridge it made.

    Attributes
    ----------
    hosts : dict of str to Host
    local_address : str
        This process's address as the hosts see it (the bridge's, or ``127.0.0.1``).
    """

    def __init__(self, names: Sequence[str], *, namespaces: bool) -> None:
        self.names = list(names)
        self.namespaces = namespaces
        self.tag = f"{os.getpid() % 100000}"
        self.net = f"{SUBNET}.{os.getpid() % 250 + 1}"
        if namespaces:  # known before the hosts are made: command lines can name them
            self.hosts = {name: Host(name, f"{self.net}.{i}", f"hw{self.tag}-{name}")
                          for i, name in enumerate(self.names, start=2)}
            self.local_address = f"{self.net}.1"
        else:
            self.hosts = {name: Host(name, "127.0.0.1") for name in self.names}
            self.local_address = "127.0.0.1"
        self._made: list[tuple[str, ...]] = []

    def __enter__(self) -> Network:
        if not self.namespaces:
            return self
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        return self

    def _run(self, *argv: str) -> None:
        done = _ip(*argv)
        if done.returncode != 0:
            raise RuntimeError(f"ip {' '.join(argv)} failed: {done.stderr.strip()}")

    def _build(self) -> None:
        bridge = f"hw{self.tag}br"
        self._run("link", "add", bridge, "type", "bridge")
        self._made.append(("link", "del", bridge))
        self._run("addr", "add", f"{self.local_address}/24", "dev", bridge)
        self._run("link", "set", bridge, "up")
        for i, name in enumerate(self.names, start=2):
            host = self.hosts[name]
            ns, veth, peer = str(host.netns), f"hw{self.tag}v{i}", f"hw{self.tag}p{i}"
            self._run("netns", "add", ns)
            self._made.append(("netns", "del", ns))
            self._run("link", "add", veth, "type", "veth", "peer", "name", peer)
            self._made.append(("link", "del", veth))
            self._run("link", "set", veth, "master", bridge)
            self._run("link", "set", veth, "up")
            self._run("link", "set", peer, "netns", ns)
            self._run("-n", ns, "link", "set", peer, "name", "eth0")
            self._run("-n", ns, "addr", "add", f"{host.address}/24", "dev", "eth0")
            self._run("-n", ns, "link", "set", "eth0", "up")
            self._run("-n", ns, "link", "set", "lo", "up")

    def close(self) -> None:
        """Remove what was made (last first); what is already gone is ignored."""
        while self._made:
            _ip(*self._made.pop())

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()
