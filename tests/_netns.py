"""Separate "hosts" on one machine for multi-host tests: Linux network namespaces.

A hub namespace holds a bridge device ``br0``; every host namespace is joined to it by a veth
pair (``eth0`` on the host's side) and has an address ``SUBNET.i``/24. Everything the hosts
send each other crosses the veths; nothing leaves the namespaces the test made, and they are
deleted on exit, also when the test fails.

Needs root and ``ip netns``. :func:`require_netns` skips a module without them, with the
reason, except where the tests must run: with ``CI`` set (CI runs as root with ``ip netns``) or
``NEHMO_REQUIRE_NETNS=1`` it fails instead, so a CI machine without namespaces cannot lose a
multi-host test to one ``-ra`` line.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass

import pytest

DEVICE = "eth0"  # a host's end of its veth (in the host's namespace)


def netns_unavailable() -> str:
    """Why network namespaces cannot be made here, or ''."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the 'ip' tool (iproute2) is not installed"
    probe = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        return f"'ip netns' is unavailable: {probe.stderr.strip()}"
    return ""


def netns_required() -> bool:
    """Whether this environment must run the test (CI, or asked for): then a missing
    ``ip netns`` is a failure, not a skip."""
    ci = os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")
    return ci or os.environ.get("NEHMO_REQUIRE_NETNS", "") == "1"


def require_netns(what: str) -> None:
    """Skip the calling module (or fail it where it must run) when namespaces cannot be made."""
    reason = netns_unavailable()
    if not reason:
        return
    if netns_required():
        pytest.fail(
            f"{what} required here (CI or NEHMO_REQUIRE_NETNS=1) but cannot run: {reason}",
            pytrace=False,
        )
    pytest.skip(f"{what} skipped: {reason} (set NEHMO_REQUIRE_NETNS=1 to fail instead)")


def ip(*args: str) -> str:
    """Run ``ip <args>``; its output (raises with ip's message on failure)."""
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


def own_namespaces(prefix: str) -> list[str]:
    """The namespaces whose names start with ``prefix`` that exist."""
    names = (line.split()[0] for line in ip("netns", "list").splitlines() if line.strip())
    return [n for n in names if n.startswith(prefix)]


@dataclass(frozen=True)
class Host:
    name: str  # role
    netns: str
    address: str

    def rx_bytes(self) -> int:
        """Bytes received so far on the host's veth end."""
        path = f"/sys/class/net/{DEVICE}/statistics/rx_bytes"
        done = subprocess.run(
            ["ip", "netns", "exec", self.netns, "cat", path],
            capture_output=True,
            text=True,
            timeout=30,
            check=True,
        )
        return int(done.stdout)

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this host's namespace."""
        return ["ip", "netns", "exec", self.netns, *argv]


@contextmanager
def hosts(prefix: str, subnet: str, roles: list[str]) -> Iterator[dict[str, Host]]:
    """One namespace per role (named ``prefix`` + role), each joined by a veth pair to ``br0``
    in a hub namespace, addresses ``subnet.1``, ``subnet.2`` …; all namespaces (and with them
    the veth and bridge devices) are deleted on exit."""
    hub = prefix + "hub"
    made: list[str] = []
    try:
        ip("netns", "add", hub)
        made.append(hub)
        ip("-n", hub, "link", "set", "lo", "up")
        ip("-n", hub, "link", "add", "br0", "type", "bridge")
        ip("-n", hub, "link", "set", "br0", "up")
        out: dict[str, Host] = {}
        for i, role in enumerate(roles, start=1):
            host = Host(role, prefix + role.replace("_", ""), f"{subnet}.{i}")
            ip("netns", "add", host.netns)
            made.append(host.netns)
            port = f"veth{i}"  # the hub's end
            ip("-n", hub, "link", "add", port, "type", "veth", "peer", "name", DEVICE, "netns",
               host.netns)  # fmt: skip
            ip("-n", hub, "link", "set", port, "master", "br0")
            ip("-n", hub, "link", "set", port, "up")
            ip("-n", host.netns, "link", "set", "lo", "up")
            ip("-n", host.netns, "addr", "add", f"{host.address}/24", "dev", DEVICE)
            ip("-n", host.netns, "link", "set", DEVICE, "up")
            # subnet discovery announces itself by multicast: route it out of the veth.
            ip("-n", host.netns, "route", "add", "224.0.0.0/4", "dev", DEVICE)
            out[role] = host
        yield out
    finally:
        for netns in reversed(made):
            with suppress(RuntimeError, subprocess.SubprocessError):
                ip("netns", "del", netns)
