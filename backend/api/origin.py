"""Host and Origin checks: only the studio's own pages may drive the server (CSRF and DNS rebinding).

Any web page the user visits can send requests to a server on 127.0.0.1. Two headers tell them apart:

* ``Host`` names the server the browser thinks it talks to. A DNS-rebinding page (``evil.example`` re-pointed at
  127.0.0.1) sends ``Host: evil.example``, so every request, GET included, must name one of our addresses with
  one of our ports.
* ``Origin`` names the page that sent a request; browsers send it on every cross-origin request and on
  state-changing ones (POST, PUT, PATCH, DELETE) and websocket handshakes. When present there it must be one of
  ours too. Requests without it (curl, the CLI, in-process test clients) pass on the Host check alone.

Ours are the loopback names (``127.0.0.1``, ``localhost``, ``::1``) and the bound address, each with the API's
or the viewer's port. A server bound to every interface (``0.0.0.0``, ``::``) also answers to any IP literal
and to the machine's host name on those ports: an IP literal cannot be rebound.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from urllib.parse import urlsplit

from backend.core.errors import shorten

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
_WILDCARDS = ("0.0.0.0", "::", "")
_DEFAULT_PORTS = {"http": 80, "https": 443, "ws": 80, "wss": 443}


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class OriginPolicy:
    """The host names and ports this server answers to (see the module docstring)."""

    names: frozenset[str]
    """Lower-case host names and addresses, IPv6 without brackets."""
    ports: frozenset[int]
    any_ip: bool = False
    """Bound to every interface: any IP-literal host is one of ours."""

    @classmethod
    def for_server(cls, bind_host: str, ports: Iterable[int]) -> OriginPolicy:
        """The policy of a server bound to ``bind_host`` whose pages are served on ``ports`` (API, viewer)."""
        host = bind_host.strip("[]").lower()
        names = set(LOOPBACK_NAMES)
        wildcard = host in _WILDCARDS
        if wildcard:
            names.update(n.lower() for n in (socket.gethostname(), socket.getfqdn()) if n)
        else:
            names.add(host)
        return cls(frozenset(names), frozenset(ports), any_ip=wildcard)

    def authority_ok(self, authority: str, scheme: str = "http") -> bool:
        """Whether ``host[:port]`` (a Host header, an origin's netloc) is this server's."""
        try:
            parts = urlsplit(f"//{authority}")
            port = parts.port or _DEFAULT_PORTS.get(scheme)
        except ValueError:  # a port that is no number or out of range
            return False
        host = (parts.hostname or "").lower()
        if port not in self.ports or not host or parts.username is not None or parts.path:
            return False
        return host in self.names or (self.any_ip and _is_ip(host))

    def origin_ok(self, origin: str) -> bool:
        """Whether an ``Origin`` header (``scheme://host[:port]``) is one of this server's pages."""
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and self.authority_ok(parts.netloc, parts.scheme)


def refusal(policy: OriginPolicy | None, method: str, headers: Mapping[str, str], websocket: bool = False
            ) -> tuple[str, str] | None:
    """``(message, header)`` when a request must be refused with a 403, else None.

    ``policy`` None checks only that an ``Origin`` on a state-changing request (or a websocket handshake) is the
    request's own ``Host`` (an in-process app with no address of its own, e.g. under a test client).
    """
    host = headers.get("host", "")
    if policy is not None and not policy.authority_ok(host):
        return (f"Host {shorten(host)} is not this server; open the URL the server printed "
                "(a page that renamed the server, as in DNS rebinding, is refused)", "Host")
    origin = headers.get("origin")
    if origin is None or not (websocket or method.upper() in STATE_CHANGING):
        return None
    same = urlsplit(origin).netloc.lower() == host.lower() and urlsplit(origin).scheme in ("http", "https")
    if not same and (policy is None or not policy.origin_ok(origin)):
        return (f"Origin {shorten(origin)} is not one of this server's pages; requests that change state are "
                "taken only from the studio and the API docs", "Origin")
    return None
