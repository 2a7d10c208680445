"""Who may talk to the viewer: the pages it served itself, and with a token when it is exposed.

viser serves its browser client over HTTP and the run over a websocket, on one port. A browser
lets any web page open a websocket to 127.0.0.1 (websockets have no same-origin rule) and lets
a page whose host name its author re-points at 127.0.0.1 (DNS rebinding) send requests there;
either would read the run's scene and story and press the viewer's buttons. So every request,
a plain HTTP one or a websocket's opening handshake, passes :meth:`ViewerAccess.refusal` first:

- its ``Host`` header names the viewer's own address: the bound host at the bound port, and for
  a loopback bind also ``localhost``, ``127.0.0.1`` and ``[::1]`` at that port. A wildcard bind
  (``0.0.0.0``, ``::``) answers on every address of the machine under any name, so there any
  ``Host`` passes and the token is what keeps others out;
- its ``Origin`` header, when it has one, is ``http://`` + that ``Host``: a page of another
  site (or a sandboxed ``null`` origin) never gets an answer;
- when the viewer listens beyond this machine (a host that is not loopback) the request carries
  the token made for this viewer (:func:`secrets.token_urlsafe`): as ``?token=...`` (the URL
  ``storyteller view`` prints; the websocket URL may carry it too) or as the cookie set on the
  answer to that URL (``HttpOnly; SameSite=Strict``: another site's page cannot send it).

Guarantee: a request that fails any rule gets ``403`` and one line saying which rule, nothing
from the run; a websocket's handshake fails before any message is sent. Pure: the hook that
applies it to viser's server is :mod:`.guarded_server`.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")
WILDCARD_HOSTS = ("0.0.0.0", "::", "")
TOKEN_PARAM = "token"
TOKEN_BYTES = 24  # secrets.token_urlsafe(24): 32 characters, 192 random bits


def is_loopback(host: str) -> bool:
    """Whether binding ``host`` keeps the viewer on this machine."""
    name = host.strip().lower().removeprefix("[").removesuffix("]")
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def authority(host: str, port: int) -> str:
    """``host:port`` as a browser writes it in ``Host`` and ``Origin`` (IPv6 in brackets)."""
    name = host.strip().lower()
    if ":" in name and not name.startswith("["):
        name = f"[{name}]"
    return f"{name}:{port}"


@dataclass(frozen=True)
class ViewerAccess:
    """The access rule of one viewer: the host it binds and its token (None on loopback)."""

    host: str
    token: str | None

    @classmethod
    def for_host(cls, host: str) -> ViewerAccess:
        """The rule for a viewer bound to ``host``: a fresh token unless it is loopback."""
        return cls(host=host, token=None if is_loopback(host) else secrets.token_urlsafe(TOKEN_BYTES))

    @property
    def wildcard(self) -> bool:
        return self.host.strip() in WILDCARD_HOSTS

    def own_authorities(self, port: int) -> frozenset[str]:
        """The ``Host`` values that name this viewer (empty for a wildcard bind: any)."""
        if self.wildcard:
            return frozenset()
        names = {self.host, *LOOPBACK_NAMES} if is_loopback(self.host) else {self.host}
        found = {authority(n, port) for n in names}
        if port == 80:  # a browser leaves the default port out
            found |= {a.removesuffix(":80") for a in found}
        return frozenset(found)

    def cookie_name(self, port: int) -> str:
        """The token cookie's name (cookies are not kept apart by port; the name is)."""
        return f"storyteller_view_{port}"

    def set_cookie(self, port: int) -> str:
        """The ``Set-Cookie`` value that hands the token to the page the URL opened."""
        return f"{self.cookie_name(port)}={self.token}; Path=/; HttpOnly; SameSite=Strict"

    def url_token(self, path: str) -> str | None:
        """The ``?token=`` of a request path, if any."""
        values = parse_qs(urlsplit(path).query).get(TOKEN_PARAM, [])
        return values[0] if len(values) == 1 else None

    def refusal(
        self,
        *,
        path: str,
        hosts: Sequence[str],
        origins: Sequence[str],
        cookies: Sequence[str],
        port: int,
    ) -> str | None:
        """Why a request must be refused (one line), or None when it may pass. ``hosts``,
        ``origins`` and ``cookies`` are every value of those headers, ``port`` the port the
        connection came in on."""
        if len(hosts) != 1:
            return "a request needs exactly one Host header"
        host = hosts[0].strip().lower()
        own = self.own_authorities(port)
        if (own and host not in own) or not host:
            return "the Host header does not name this viewer"
        if len(origins) > 1:
            return "a request may carry one Origin header"
        if origins and origins[0].strip().lower() != f"http://{host}":
            return "the request comes from a page this viewer did not serve"
        if self.token is not None and not self._has_token(path, cookies, port):
            return "this viewer needs the token of the URL `storyteller view` printed"
        return None

    def _has_token(self, path: str, cookies: Sequence[str], port: int) -> bool:
        assert self.token is not None
        offered = [self.url_token(path)]
        name = self.cookie_name(port)
        for header in cookies:
            for pair in header.split(";"):
                key, _, value = pair.strip().partition("=")
                if key == name:
                    offered.append(value)
        expected = self.token.encode()
        return any(t is not None and hmac.compare_digest(t.encode("utf-8", "replace"), expected) for t in offered)
