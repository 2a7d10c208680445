"""Session-wide test setup: no test reaches the network unless it says so.

Any ``connect`` (or name lookup) to a non-loopback address raises :class:`NetworkBlockedError`.
Loopback (127.0.0.0/8, ::1, localhost) and Unix sockets stay allowed, for local fake
providers. A test that truly needs the network is marked ``@pytest.mark.allow_network``.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from collections.abc import Iterator
from typing import Any

os.environ["LITELLM_LOCAL_MODEL_COST_MAP"] = "True"  # before anything imports litellm

import pytest


class NetworkBlockedError(OSError):
    """A test tried to reach a non-loopback host."""


def _is_loopback(host: Any) -> bool:
    if not isinstance(host, str):
        return False
    if host in ("localhost", "", "localhost.localdomain"):
        return True
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


_real_connect = socket.socket.connect
_real_connect_ex = socket.socket.connect_ex
_real_getaddrinfo = socket.getaddrinfo


def _check(sock: socket.socket, address: Any) -> None:
    if sock.family == getattr(socket, "AF_UNIX", object()):
        return
    host = address[0] if isinstance(address, tuple) and address else address
    if not _is_loopback(host):
        raise NetworkBlockedError(f"network access to {address!r} is blocked in tests (mark the test allow_network)")


def _guarded_connect(self: socket.socket, address: Any) -> None:
    _check(self, address)
    return _real_connect(self, address)


def _guarded_connect_ex(self: socket.socket, address: Any) -> int:
    _check(self, address)
    return _real_connect_ex(self, address)


def _guarded_getaddrinfo(host: Any, *args: Any, **kwargs: Any) -> Any:
    if host is not None and not _is_loopback(host.decode() if isinstance(host, bytes) else host):
        raise NetworkBlockedError(f"name lookup of {host!r} is blocked in tests (mark the test allow_network)")
    return _real_getaddrinfo(host, *args, **kwargs)


_guard = pytest.MonkeyPatch()  # session-wide: installed at configure, undone per allow_network test


def _install_guard() -> None:
    _guard.setattr(socket.socket, "connect", _guarded_connect)
    _guard.setattr(socket.socket, "connect_ex", _guarded_connect_ex)
    _guard.setattr(socket, "getaddrinfo", _guarded_getaddrinfo)


def _remove_guard() -> None:
    _guard.undo()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "allow_network: the test may open non-loopback connections")
    _install_guard()


@pytest.fixture(autouse=True)
def _network_guard(request: pytest.FixtureRequest) -> Iterator[None]:
    if request.node.get_closest_marker("allow_network") is None:
        yield
        return
    _remove_guard()
    try:
        yield
    finally:
        _install_guard()
