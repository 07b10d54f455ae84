"""Token check for servers bound beyond loopback.

On 127.0.0.1 no token is needed. Otherwise every API call and the studio page
must present the token: ``Authorization: Bearer <token>``, ``?token=<token>``
(for the first page load) or the ``calib_token`` cookie that the first load sets.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets

from fastapi import Request

COOKIE = "calib_token"


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    return secrets.token_urlsafe(24)


def presented_token(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip()
    return request.query_params.get("token") or request.cookies.get(COOKIE)


def token_ok(expected: str | None, presented: str | None) -> bool:
    if expected is None:
        return True
    return presented is not None and hmac.compare_digest(expected.encode(), presented.encode())
