"""The viewer attack: a live ``view`` server sent forged Origin and Host headers, websocket
upgrades from another or a null origin, path traversals (encoded, backslashed, NUL, 100 KB long),
Host names that only look like the viewer's, a websocket frame claiming 2**40 bytes, and a run
folder whose ``live.json`` is a sparse 3 GB file (the viewer polls it).
"""

from __future__ import annotations

import contextlib
import http.client
import os
import signal
import socket
import struct
import subprocess
import tempfile
import time

from storyteller.benchmark.hostile.harness import CLI, RSS_LIMIT, Box, sparse_file
from storyteller.benchmark.hostile.judging import Outcome, limit_child


def _viewer_requests(box: Box, url: str) -> str | None:
    host, port = url.removeprefix("http://").split("/")[0].rsplit(":", 1)

    def get(path: str, headers: dict[str, str]) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection(host, int(port), timeout=5)
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        for k, v in {"Host": f"{host}:{port}", **headers}.items():
            conn.putheader(k, v)
        conn.endheaders()
        res = conn.getresponse()
        body = res.read(1 << 20)
        conn.close()
        return res.status, body

    ws = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
          "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="}
    problems = []
    if get("/", {"Origin": "http://evil.example"})[0] != 403:
        problems.append("page answered to another origin")
    if get("/", {"Host": "evil.example"})[0] != 403:
        problems.append("page answered to a rebound host name")
    if get("/", {**ws, "Origin": "http://evil.example"})[0] == 101:
        problems.append("websocket opened for another origin")
    if get("/", {**ws, "Origin": "null"})[0] == 101:
        problems.append("websocket opened for a null origin")
    for path in ("/../../../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "//etc/passwd",
                 "/..%2f..%2f..%2f..%2fetc%2fpasswd", "/" + "a/" * 20_000, "/%00", "/..\\..\\..\\..\\etc\\passwd",
                 "/..%5c..%5c..%5c..%5cetc%5cpasswd", "/%252e%252e/%252e%252e/etc/passwd", "/" + "a" * 100_000):
        with contextlib.suppress(OSError, http.client.HTTPException):
            _status, body = get(path, {})
            if b"root:" in body:
                problems.append(f"served /etc/passwd for {path[:30]}")
    for forged in (f"127.0.0.1.evil.com:{port}", f"localhost.:{port}", f"evil.com@{host}:{port}", host, ""):
        with contextlib.suppress(OSError, http.client.HTTPException):
            if get("/", {"Host": forged})[0] == 200:
                problems.append(f"page answered to Host {forged!r}")
    if get("/", {**ws, "Origin": f"http://{host}:{port}.evil.com"})[0] == 101:
        problems.append("websocket opened for an origin that only starts like the viewer's")
    # A websocket of the right origin sends a frame claiming 2**40 bytes: the server must live on.
    with contextlib.suppress(OSError), socket.create_connection((host, int(port)), timeout=5) as s:
        lines = ["GET / HTTP/1.1", f"Host: {host}:{port}", f"Origin: http://{host}:{port}",
                 *(f"{k}: {v}" for k, v in ws.items()), "", ""]
        s.sendall("\r\n".join(lines).encode())
        s.recv(4096)
        s.sendall(b"\x82\xff" + struct.pack(">Q", 1 << 40) + b"\0\0\0\0" + b"\0" * (1 << 20))
    if get("/", {})[0] != 200:
        problems.append("viewer stopped answering after a huge websocket frame")
    return "; ".join(problems) or None


VIEWER_KIND = ("viewer", "forged Origin / Host, websocket, traversals, a 2**40-byte frame, 3 GB live.json")


def run_viewer(box: Box, env: dict[str, str]) -> Outcome:
    box.copy_run()
    sparse_file(box.run / "live.json", 3 << 30)  # polled while the viewer runs: must not be read whole
    start = time.monotonic()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([*CLI, "view", str(box.run), "--port", "0"], stdout=subprocess.PIPE, stderr=err, env=env,
                                preexec_fn=limit_child, start_new_session=True)
        problems: list[str] = []
        rss = 0
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline().decode("utf-8", "replace")
            url = next((w for w in line.split() if w.startswith("http://")), None)
            if url is None:
                problems.append(f"no URL printed: {line[:100]!r}")
            else:
                found = _viewer_requests(box, url)
                if found:
                    problems.append(found)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            _, _, usage = os.wait4(proc.pid, 0)
            rss = usage.ru_maxrss * 1024
            proc.returncode = -1
        if rss > RSS_LIMIT:
            problems.append(f"RSS {rss >> 20} MiB")
    return Outcome(VIEWER_KIND[0], VIEWER_KIND[1], None, time.monotonic() - start, rss, problems)
