"""The viewer answers only its own pages: forged ``Origin`` and ``Host`` are refused, and with
``--host`` beyond loopback only requests that bring the printed URL's token get an answer.

The rule itself (:class:`~storyteller.orchestrator.viewer.access.ViewerAccess`) is checked on a table of
requests; then the real viewer (viser's server with the guard of
:mod:`storyteller.orchestrator.viewer.guarded_server`) is started on a free port and spoken to with the
``websockets`` client and ``http.client``, as another site's page or a DNS-rebinding page
would: a websocket from ``https://evil.example`` is refused at the handshake and receives no
byte of the run, the viewer's own origin gets the scene; a plain GET with a forged ``Host`` is
403. ``storyteller view --host 0.0.0.0`` (a subprocess: the test session refuses non-loopback
name lookups) prints a URL with a token, refuses requests without it and answers with it, by
URL or by the cookie the first answer set. With Chromium installed, a real browser opens that
URL and shows the run (the cookie reaches the websocket).
"""

from __future__ import annotations

import http.client
import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

import pytest
import viser
import zstandard
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect
from websockets.typing import Subprotocol

from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.viewer.access import ViewerAccess, is_loopback
from tests.support.tiny_run import write_tiny_run

if TYPE_CHECKING:  # imported by the fixture, when a test needs the viewer
    from storyteller.orchestrator.viewer.server import ViewerApp

SECRET = "secretinstruction"  # the run's instruction: in the panel markdown sent to a client
PROTOCOL = Subprotocol(f"viser-v{viser.__version__}")


# ----- the rule ---------------------------------------------------------------------------------
def _refusal(access: ViewerAccess, *, host: str = "127.0.0.1:8080", origin: str | None = None,
             path: str = "/", cookie: str | None = None) -> str | None:  # fmt: skip
    return access.refusal(path=path, hosts=[host], origins=[origin] if origin else [],
                          cookies=[cookie] if cookie else [], port=8080)  # fmt: skip


def test_a_loopback_viewer_answers_its_own_addresses_and_origins_only() -> None:
    access = ViewerAccess.for_host("127.0.0.1")
    assert access.token is None
    for own in ("127.0.0.1:8080", "localhost:8080", "LOCALHOST:8080", "[::1]:8080"):
        assert _refusal(access, host=own) is None, own
        assert _refusal(access, host=own, origin=f"http://{own}") is None, own
    assert _refusal(access, origin="https://evil.example") is not None
    assert _refusal(access, origin="http://localhost:8080") is not None  # not the page's own Host
    assert _refusal(access, origin="null") is not None  # a sandboxed frame, a file:// page
    assert _refusal(access, origin="http://127.0.0.1:8081") is not None
    for forged in ("evil.example:8080", "127.0.0.1:8081", "127.0.0.1", "127.0.0.1.evil.example:8080", ""):
        assert _refusal(access, host=forged) is not None, forged
    assert access.refusal(path="/", hosts=[], origins=[], cookies=[], port=8080) is not None
    two = ["127.0.0.1:8080", "evil.example:8080"]
    assert access.refusal(path="/", hosts=two, origins=[], cookies=[], port=8080) is not None


def test_beyond_loopback_every_request_needs_the_token() -> None:
    access = ViewerAccess.for_host("0.0.0.0")
    token = access.token
    assert token is not None and len(token) >= 32
    assert ViewerAccess.for_host("0.0.0.0").token != token  # one per viewer
    assert access.wildcard and _refusal(access, host="myhost.lan:8080") is not None  # no token
    assert _refusal(access, host="myhost.lan:8080", path=f"/?token={token}") is None  # any name, with it
    assert _refusal(access, host="myhost.lan:8080", cookie=f"a=b; storyteller_view_8080={token}") is None
    assert _refusal(access, path="/?token=wrong") is not None
    assert _refusal(access, cookie=f"storyteller_view_9999={token}") is not None  # another port's cookie
    assert _refusal(access, path=f"/?token={token}&token={token}") is not None  # one token, not a list
    assert _refusal(access, path=f"/?token={token}", origin="https://evil.example") is not None
    assert _refusal(access, host="myhost.lan:8080", path=f"/?token={token}",
                    origin="http://myhost.lan:8080") is None  # fmt: skip
    lan = ViewerAccess.for_host("192.168.1.5")
    assert lan.token is not None and not lan.wildcard
    assert _refusal(lan, host="192.168.1.5:8080", path=f"/?token={lan.token}") is None
    assert _refusal(lan, host="evil.example:8080", path=f"/?token={lan.token}") is not None
    assert "HttpOnly" in access.set_cookie(8080) and "SameSite=Strict" in access.set_cookie(8080)
    assert [is_loopback(h) for h in ("127.0.0.1", "localhost", "::1", "[::1]", "127.5.0.1", "0.0.0.0", "10.0.0.1")] == [
        True, True, True, True, True, False, False,
    ]  # fmt: skip


# ----- the real viewer --------------------------------------------------------------------------
def ws_receive(url: str, headers: dict[str, str]) -> bytes:
    """Open a websocket as a browser page would and gather what the viewer sends in 2 s of
    quiet: each message's msgpack payload (viser zstd-compresses it after a 16-byte header)."""
    got = b""
    with connect(url, subprotocols=[PROTOCOL], additional_headers=headers, open_timeout=10, max_size=None) as ws:
        try:
            while True:
                message = ws.recv(timeout=2.0)
                assert isinstance(message, bytes)
                size = int.from_bytes(message[8:16], "little")
                got += zstandard.ZstdDecompressor().decompress(message[16 : 16 + size])
        except TimeoutError:
            pass
    return got


def ws_refused(url: str, headers: dict[str, str]) -> int:
    """The HTTP status of a refused websocket handshake (fails the test if it was accepted)."""
    with pytest.raises(InvalidStatus) as refused:
        ws_receive(url, headers)
    return refused.value.response.status_code


def http_get(port: int, path: str = "/", host: str | None = None, headers: dict[str, str] | None = None) -> http.client.HTTPResponse:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.putrequest("GET", path, skip_host=True)
    conn.putheader("Host", host or f"127.0.0.1:{port}")
    for key, value in (headers or {}).items():
        conn.putheader(key, value)
    conn.endheaders()
    response = conn.getresponse()
    response.read()
    conn.close()
    return response


@pytest.fixture(scope="module")
def viewer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ViewerApp, int]]:
    from storyteller.orchestrator.viewer.server import ViewerApp

    folder = write_tiny_run(tmp_path_factory.mktemp("access") / "run", instruction=SECRET)
    app = ViewerApp(folder, port=0)
    assert app.reload_if_changed()
    try:
        yield app, app.server.get_port()
    finally:
        app.stop()


@pytest.mark.slow
def test_a_websocket_from_another_site_gets_nothing_and_the_viewers_own_page_gets_the_run(viewer: tuple[ViewerApp, int]) -> None:
    _, port = viewer
    url = f"ws://127.0.0.1:{port}"
    assert ws_refused(url, {"Origin": "https://evil.example"}) == 403
    assert ws_refused(url, {"Origin": "null"}) == 403
    own = ws_receive(url, {"Origin": f"http://127.0.0.1:{port}"})
    assert SECRET.encode() in own and len(own) > 10_000  # the scene and the story
    assert SECRET.encode() in ws_receive(url, {})  # a program, not a page (no Origin)


def test_dns_rebinding_is_refused_on_http_and_the_websocket(viewer: tuple[ViewerApp, int]) -> None:
    _, port = viewer
    assert http_get(port).status == 200
    assert http_get(port, host=f"localhost:{port}").status == 200
    forged = http_get(port, host=f"evil.example:{port}")
    assert forged.status == 403
    assert http_get(port, host=f"evil.example:{port}", headers={"Origin": f"http://evil.example:{port}"}).status == 403
    # a rebinding page's websocket: its own origin, its own host name, our port
    assert ws_refused(f"ws://127.0.0.1:{port}", {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}) == 403


def test_the_viewer_never_opens_a_share_tunnel(viewer: tuple[ViewerApp, int]) -> None:
    app, _ = viewer
    assert app.server.request_share_url() is None


def test_a_viser_that_builds_its_server_otherwise_is_not_served(monkeypatch: pytest.MonkeyPatch) -> None:
    from storyteller.orchestrator.viewer import guarded_server as hook

    monkeypatch.setattr(hook, "viser_infra", SimpleNamespace(__name__="viser.somewhere_else"))
    with pytest.raises(hook.ViserHookError, match="does not serve"):
        hook.guarded_server(ViewerAccess.for_host("127.0.0.1"), port=0, verbose=False)


# ----- storyteller view --host 0.0.0.0 ----------------------------------------------------------
@pytest.fixture(scope="module")
def exposed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """``storyteller view --host 0.0.0.0`` running: (its printed output, the URL it printed)."""
    tmp = tmp_path_factory.mktemp("exposed")
    folder = write_tiny_run(tmp / "run", instruction=SECRET)
    log = tmp / "view.log"
    with log.open("w") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", "view", str(folder),
             "--port", "0", "--host", "0.0.0.0"],
            stdout=sink, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (m := re.search(r"viewing .* at (http://\S+)", log.read_text())):
            assert proc.poll() is None and time.monotonic() < deadline, f"storyteller view printed no URL: {log.read_text()}"
            time.sleep(0.2)
        time.sleep(0.5)  # the second line
        yield log.read_text(), m.group(1)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_an_exposed_viewer_prints_a_url_with_its_token_and_says_who_can_reach_it(exposed: tuple[str, str]) -> None:
    output, url = exposed
    token = urlsplit(url).query.removeprefix("token=")
    assert len(token) >= 32 and urlsplit(url).query == f"token={token}"
    assert "every address of this machine" in output and "any machine that can reach it" in output
    assert "╭" not in output and "viser" not in output  # viser's own banner (URLs without the token) is not shown


@pytest.mark.slow
def test_an_exposed_viewer_answers_only_requests_with_its_token(exposed: tuple[str, str]) -> None:
    _, url = exposed
    parts = urlsplit(url)
    port, token = int(parts.port or 0), parts.query.removeprefix("token=")
    own = {"Origin": f"http://127.0.0.1:{port}"}
    assert http_get(port).status == 403
    assert http_get(port, path="/?token=wrong").status == 403
    assert ws_refused(f"ws://127.0.0.1:{port}", own) == 403
    assert ws_refused(f"ws://127.0.0.1:{port}/?token=wrong", own) == 403
    assert ws_refused(f"ws://127.0.0.1:{port}/?token={token}", {"Origin": "https://evil.example"}) == 403
    page = http_get(port, path=f"/?token={token}")
    assert page.status == 200
    cookie = page.getheader("Set-Cookie") or ""
    assert cookie.startswith(f"storyteller_view_{port}={token};") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert SECRET.encode() in ws_receive(f"ws://127.0.0.1:{port}/?token={token}", own)
    assert SECRET.encode() in ws_receive(f"ws://127.0.0.1:{port}", {**own, "Cookie": cookie.split(";")[0]})


@pytest.mark.skipif(chromium_binary() is None, reason="chromium is not installed")
def test_a_browser_opens_the_printed_url_and_sees_the_run(exposed: tuple[str, str], tmp_path: Path) -> None:
    _, url = exposed
    parts = urlsplit(url)
    local = f"http://127.0.0.1:{parts.port}/?{parts.query}"  # the host name printed may not resolve here
    with Chromium(tmp_path / "profile") as browser:
        browser.navigate(local)
        browser.wait_for(f"document.body.innerText.includes({json.dumps(SECRET)})")  # over the websocket
