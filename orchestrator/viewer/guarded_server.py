"""The one place that reaches into viser: a ``ViserServer`` that answers only what its
:class:`~.access.ViewerAccess` lets pass, and never opens a share tunnel.

viser (pinned: 1.1.1) builds its websockets server inside ``WebsockServer._background_worker``
and hands ``websockets.asyncio.server.serve`` its own ``process_request`` (the file server of
its browser client); it offers no hook for another. :func:`guarded_server` constructs the
server while ``websockets.asyncio.server.serve`` is a subclass that puts the access check in
front of viser's ``process_request`` (websockets' documented handshake hook, which sees plain
HTTP requests and websocket handshakes alike) and adds the token cookie to the answer of a
request that brought the token in its URL; it also hands viser's handler each connection through
:func:`~.inbound.checked_handler` (only messages that decode reach viser) and lowers the message
size limit to :data:`~.inbound.MAX_MESSAGE_BYTES`. Only the ``serve`` call made by viser's own handler
during that construction is changed: constructions are serialised by a lock, and the original
``serve`` is back before :func:`guarded_server` returns. If viser did not call ``serve`` that
way (it changed), :class:`ViserHookError` is raised instead of serving unguarded; the tests in
``tests/orchestrator/viewer/test_viewer_access.py`` check the guard against the real server.

viser also lets any connected page ask for a public share URL (a tunnel through
share.viser.studio): :class:`_ViewerServer` refuses that (no network at run time, nothing
published), and :mod:`.server` hides the button. The banner viser prints at start (its URLs,
without the token) is not shown: the command prints the URL to open.
"""

from __future__ import annotations

import contextlib
import http
import inspect
import io
import socket
import threading
from collections.abc import Awaitable, Callable
from typing import Any

import viser
import viser.infra._infra as viser_infra
import websockets.asyncio.server as ws_server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from storyteller.orchestrator.viewer.access import ViewerAccess
from storyteller.orchestrator.viewer.inbound import MAX_MESSAGE_BYTES, checked_handler

ProcessRequest = Callable[[ServerConnection, Request], Awaitable[Response | None] | Response | None]


class ViserHookError(RuntimeError):
    """viser no longer builds its server the way :func:`guarded_server` expects."""


def guard_requests(access: ViewerAccess, inner: ProcessRequest | None) -> ProcessRequest:
    """A websockets ``process_request``: ``access`` first, then ``inner`` (viser's file server)."""

    async def process_request(connection: ServerConnection, request: Request) -> Response | None:
        port = int(connection.local_address[1])
        headers = request.headers
        refusal = access.refusal(
            path=request.path,
            hosts=headers.get_all("Host"),
            origins=headers.get_all("Origin"),
            cookies=headers.get_all("Cookie"),
            port=port,
        )
        if refusal is not None:
            return connection.respond(http.HTTPStatus.FORBIDDEN, f"refused: {refusal}\n")
        response = inner(connection, request) if inner is not None else None
        if inspect.isawaitable(response):
            response = await response
        if response is not None and access.token is not None and access.url_token(request.path):
            response.headers["Set-Cookie"] = access.set_cookie(port)
        return response

    return process_request


class _GuardedServe(ws_server.serve):
    """``websockets.asyncio.server.serve`` with the pending guard in front of viser's hook, and
    viser's handler given only messages that decode."""

    def __init__(self, handler: Any, *args: Any, process_request: ProcessRequest | None = None, **kwargs: Any) -> None:
        access = _pending.access
        if access is not None and getattr(handler, "__module__", None) == viser_infra.__name__:
            process_request = guard_requests(access, process_request)
            handler = checked_handler(handler, _pending.gui_values)
            kwargs["max_size"] = MAX_MESSAGE_BYTES
            _pending.applied += 1
        super().__init__(handler, *args, process_request=process_request, **kwargs)


class GuiValues:
    """The current value of an input of ``server``'s panel or of one page's own panel, by uuid
    (None: no such input, or the server is still being built), for :func:`~.inbound.update_problem`."""

    def __init__(self) -> None:
        self.server: viser.ViserServer | None = None

    def __call__(self, uuid: str) -> object:
        server = self.server
        if server is None:
            return None
        for gui in (server.gui, *(client.gui for client in server.get_clients().values())):
            handle = gui._gui_input_handle_from_uuid.get(uuid)  # viser 1.1.1's table of inputs
            if handle is not None:
                return handle._impl.value
        return None


class _Pending:
    """The guard of the construction under way (one at a time, under ``lock``)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.access: ViewerAccess | None = None
        self.applied = 0
        self.gui_values = GuiValues()


_pending = _Pending()


class _ViewerServer(viser.ViserServer):
    """A ``ViserServer`` that never asks share.viser.studio for a public URL."""

    def request_share_url(self, verbose: bool = True) -> str | None:
        return None


def check_listenable(host: str) -> None:
    """Raise ``OSError`` when this machine cannot listen on ``host`` (viser would try 1,000
    ports there and then wait for ever)."""
    family = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0][0]
    with socket.create_server((host, 0), family=family):
        pass


def guarded_server(access: ViewerAccess, *, port: int, **kwargs: Any) -> viser.ViserServer:
    """A started ``ViserServer`` on ``access.host`` and ``port`` (the next free one when
    taken) whose every HTTP request and websocket handshake passes ``access`` first. An
    address this machine cannot listen on raises ``OSError``."""
    check_listenable(access.host)
    with _pending.lock:
        original = ws_server.serve
        _pending.access, _pending.applied, _pending.gui_values = access, 0, GuiValues()
        gui_values = _pending.gui_values
        ws_server.serve = _GuardedServe  # type: ignore[misc]  # a subclass, for this construction only
        try:  # viser prints a banner with its own URLs (no token), whatever ``verbose`` says
            with contextlib.redirect_stdout(io.StringIO()):
                server = _ViewerServer(host=access.host, port=port, **kwargs)
        finally:
            ws_server.serve = original  # type: ignore[misc]  # restoring the server method patched above
            _pending.access = None
        applied = _pending.applied
    gui_values.server = server
    if applied == 0:
        server.stop()
        raise ViserHookError(
            f"viser {viser.__version__} did not build its server through websockets' serve() with its own "
            "handler: the viewer cannot check who connects, so it does not serve"
        )
    return server
