"""Session-wide test setup: no test reaches the network or the embedded model unless it says so.

Any ``connect`` (or name lookup) to a non-loopback address raises :class:`NetworkBlockedError`.
Loopback (127.0.0.0/8, ::1, localhost) and Unix sockets stay allowed, for local fake
providers. A test that truly needs the network is marked ``@pytest.mark.allow_network``.

Constructing ``llama_cpp.Llama`` (how :mod:`storyteller.orchestrator.llm.local_model` loads the embedded
model) raises :class:`EmbeddedModelRefusedError` in a test not marked
``@pytest.mark.embedded_model``, and such a test fails even if the code under test catches the
error (a provider error falling back to another model, say). The guard holds in this process
only: a CLI run in a child process is not covered.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import ipaddress
import os
import socket
import sys
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Any

os.environ["LITELLM_LOCAL_MODEL_COST_MAP"] = "True"  # before anything imports litellm

import pytest

if TYPE_CHECKING:
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.scene.model import Scene

pytest_plugins = ["pytester"]  # tests/test_model_guard.py runs this conftest in a child session


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


class EmbeddedModelRefusedError(RuntimeError):
    """A test not marked ``embedded_model`` tried to load the embedded llama.cpp model."""


@dataclass
class _ModelGate:
    """Whether the running test may load the embedded model, and what it tried if not."""

    allowed: bool = False
    refused: list[str] = field(default_factory=list)


_gate = _ModelGate()


_model_guard = pytest.MonkeyPatch()  # session-wide; the gate, not undo, lets marked tests through


def _refusing_new(cls: type, *args: Any, **kwargs: Any) -> Any:
    if not _gate.allowed:
        path = kwargs.get("model_path", args[0] if args else "?")
        message = (
            f"llama_cpp.Llama(model_path={str(path)!r}) refused: only a test marked "
            "@pytest.mark.embedded_model may load the embedded model (use a fake chat function, "
            "as LocalLlamaProvider(chat=...), or mark the test)"
        )
        _gate.refused.append(message)
        raise EmbeddedModelRefusedError(message)
    return object.__new__(cls)  # refused before an instance exists, so no half-built __del__


class _GuardingLoader(importlib.abc.Loader):
    """Runs ``llama_cpp.llama`` with its own loader, then guards its ``Llama``."""

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self.loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self.loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self.loader.exec_module(module)
        _model_guard.setattr(module.Llama, "__new__", _refusing_new)


class _GuardOnImport(importlib.abc.MetaPathFinder):
    """Puts the guard on ``llama_cpp.Llama`` as soon as llama-cpp-python is imported. Importing
    it up front would cost every test session its import (and llama_cpp leaves two /dev/null
    files open that warn at exit)."""

    def find_spec(self, fullname: str, path: Any, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname != "llama_cpp.llama":
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _GuardingLoader(spec.loader)
        return spec


_guard_on_import = _GuardOnImport()


def _install_model_guard() -> None:
    loaded = sys.modules.get("llama_cpp.llama")
    if loaded is not None:
        _model_guard.setattr(loaded.Llama, "__new__", _refusing_new)
    else:
        sys.meta_path.insert(0, _guard_on_import)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "allow_network: the test may open non-loopback connections")
    _install_guard()
    _install_model_guard()


def pytest_unconfigure(config: pytest.Config) -> None:
    if _guard_on_import in sys.meta_path:
        sys.meta_path.remove(_guard_on_import)
    _model_guard.undo()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    _gate.allowed = item.get_closest_marker("embedded_model") is not None
    _gate.refused = []


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    yield  # an error from the test itself propagates as it is
    if _gate.refused:
        raise EmbeddedModelRefusedError(
            f"the test passed only because it caught the refusal: {_gate.refused[0]}"
        )


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item: pytest.Item) -> None:
    _gate.allowed = False


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


@pytest.fixture(autouse=True)
def _one_name_per_module() -> Iterator[None]:
    """Fails a test after which a module of the project's folders is loaded under its folder's
    own name (``sim.x`` beside ``storyteller.sim.x``: two copies of its classes); the copies are
    dropped so that the next test starts clean (tests/support/namespace_guard.py)."""
    yield
    from tests.support.namespace_guard import second_names

    second = second_names()
    for name in second:
        del sys.modules[name]
    assert not second, f"loaded outside the storyteller namespace: {', '.join(second[:10])}"


# ----- shared fixtures --------------------------------------------------------------------
@pytest.fixture(scope="module")
def motion() -> MotionMatcher:
    """The motion matcher on the cached motion databases (one per test module)."""
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    return MotionMatcher(load_databases(cache_dir=motion_cache_dir()))


@pytest.fixture(scope="module")
def home() -> Scene:
    """The bundled home scene."""
    from storyteller.sim.scene.bundled import resolve_scene

    return resolve_scene("home")


@pytest.fixture
def env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A CLI run's environment: the fake provider's key set, no config or model from the caller's."""
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    yield
