"""Network namespaces joined by veth pairs, for the tests that put ROS participants on separate "hosts".

``with network() as net:`` gives a builder: ``net.namespace()`` makes a fresh
network namespace with only ``lo`` (up) in it, ``net.link(a, b)`` joins two
places (a namespace, or ``HOST``, the test's own namespace) with a veth pair
whose ends get the two addresses of a private /30 (10.213.x.y; on the veth
only: no route, no address, nothing outside the machine is touched). A
``Place`` runs commands inside its namespace (``place.command(argv)``:
``ip netns exec NAME argv``, which execs, so the process keeps its pid). At
the end of the block, whatever happened in it, every link and namespace made
is removed again.

Names carry the test process's pid (namespaces ``nni-<pid>-<n>``, interfaces
``nn<pid>x<n>``), so parallel runs do not collide; an address on a link to
``HOST`` is checked to be unused there first.

Needs root (``ip netns add``): where that is not permitted, or ``ip`` is
missing, the test fails with one message saying so (CI runs as root). It is
never skipped.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass

import pytest

#: Second octet of every test link's /30 (10.213.0.0/16 is private, RFC 1918).
_SECOND_OCTET = 213
#: /30 subnets of 10.213.0.0/16: 64 per third octet.
_SUBNETS = 256 * 64
_NEEDS = "this test needs root and `ip netns` (iproute2) to build its network namespaces; CI runs as root"


def ip(*args: str) -> subprocess.CompletedProcess:
    """``ip ARGS`` (iproute2), output captured; the test fails if ``ip`` is missing."""
    try:
        return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)
    except FileNotFoundError:
        pytest.fail(f"the `ip` command is missing: {_NEEDS}")


@dataclass(frozen=True)
class Place:
    """A network namespace (``name``), or the test's own one (``name`` None).

    With ``shm`` (a folder), the processes run in it see that folder as their
    ``/dev/shm``: shared memory among them, none with the rest of the machine,
    as on a host of its own.
    """

    name: str | None
    shm: str | None = None

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this namespace (``ip netns exec`` gives it a mount namespace of its own)."""
        if self.name is None:
            return list(argv)
        if self.shm is None:
            return ["ip", "netns", "exec", self.name, *argv]
        return ["ip", "netns", "exec", self.name, "sh", "-c", 'mount --bind "$0" /dev/shm && exec "$@"',
                self.shm, *argv]

    def ip_args(self, *args: str) -> tuple[str, ...]:
        """Arguments of an ``ip`` command that acts inside this namespace."""
        return args if self.name is None else ("-n", self.name, *args)


#: The namespace the test itself runs in.
HOST = Place(None)


@dataclass(frozen=True)
class End:
    """One end of a veth link: where it is, its interface name, its address."""

    place: Place
    interface: str
    address: str

    def counters(self) -> dict[str, int]:
        """The interface's packet and byte counters (``/sys/class/net/IF/statistics``, read in its namespace)."""
        names = ("rx_packets", "tx_packets", "rx_bytes", "tx_bytes")
        script = "; ".join(f"cat /sys/class/net/{self.interface}/statistics/{name}" for name in names)
        done = subprocess.run(self.place.command(["sh", "-c", script]), capture_output=True, text=True, timeout=10)
        assert done.returncode == 0, done.stderr
        return dict(zip(names, map(int, done.stdout.split())))


class Network:
    """Namespaces and links made for one test (use :func:`network`)."""

    def __init__(self):
        self._pid = os.getpid()
        self._namespaces: list[str] = []
        self._links: list[End] = []
        self._shm: list[str] = []

    def _run(self, *args: str) -> None:
        done = ip(*args)
        if done.returncode != 0:
            pytest.fail(f"cannot build the test's network: `ip {' '.join(args)}` failed ({done.stderr.strip()}); "
                        f"{_NEEDS}")

    def namespace(self, own_shm: bool = False) -> Place:
        """A fresh network namespace with ``lo`` up and nothing else; ``own_shm``: its own ``/dev/shm`` too."""
        name = f"nni-{self._pid}-{len(self._namespaces)}"
        self._run("netns", "add", name)
        self._namespaces.append(name)
        shm = None
        if own_shm:
            shm = tempfile.mkdtemp(prefix=f"{name}-", dir="/dev/shm")
            os.chmod(shm, 0o1777)
            self._shm.append(shm)
        place = Place(name, shm)
        self._run(*place.ip_args("link", "set", "lo", "up"))
        return place

    def link(self, a: Place, b: Place) -> tuple[End, End]:
        """A veth pair from ``a`` to ``b``, both ends up, addressed .1 (``a``) and .2 (``b``) of a private /30."""
        index = len(self._links) // 2
        names = (f"nn{self._pid}x{index}a", f"nn{self._pid}x{index}b")
        first, second = self._subnet(index, a, b)
        self._run("link", "add", names[0], "type", "veth", "peer", "name", names[1])
        ends = (End(a, names[0], first), End(b, names[1], second))
        self._links += ends
        for end in ends:
            if end.place.name is not None:
                self._run("link", "set", end.interface, "netns", end.place.name)
            self._run(*end.place.ip_args("addr", "add", f"{end.address}/30", "dev", end.interface))
            self._run(*end.place.ip_args("link", "set", end.interface, "up"))
        return ends

    def _subnet(self, index: int, *places: Place) -> tuple[str, str]:
        """Two addresses of a /30 of 10.213/16 from the pid, unused in ``HOST`` if a link end is there."""
        in_use = ip("-4", "-o", "addr", "show").stdout if HOST in places else ""
        for step in range(_SUBNETS):
            n = (self._pid * 7 + index + step) % _SUBNETS
            prefix = f"10.{_SECOND_OCTET}.{n // 64}."
            host = 4 * (n % 64)
            first, second = f"{prefix}{host + 1}", f"{prefix}{host + 2}"
            if f" {first}/" not in in_use and f" {second}/" not in in_use:
                return first, second
        pytest.fail(f"no free /30 in 10.{_SECOND_OCTET}.0.0/16 on this machine")

    def close(self) -> None:
        """Remove every link and namespace made (deleting one end of a veth pair deletes both)."""
        for end in self._links:
            ip(*end.place.ip_args("link", "del", end.interface))
        for name in reversed(self._namespaces):
            ip("netns", "del", name)
        for folder in self._shm:
            shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def network():
    """A :class:`Network` for the block; everything it made is removed at exit, also on failure."""
    net = Network()
    try:
        yield net
    finally:
        net.close()


@contextmanager
def host_and_namespace():
    """The test's namespace (``HOST``) and one fresh namespace, joined by a veth link: the two ends."""
    with network() as net:
        yield net.link(HOST, net.namespace())
