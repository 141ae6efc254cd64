"""Who may talk to the desk: the access token off loopback, the cross-origin guard, request size limits,
error texts without paths (the viser server's share tunnel is closed in app/scene/viser_private.py).

- Bound to loopback (the default), the desk needs no token: only this machine reaches it. Bound to any
  other address, every /api request except /api/health, and the 3-D scene under /scene (its page and its
  websocket, app/web/scene_proxy.py), need the access token: requests that change state or move the robot
  (every method but GET and HEAD) carry it as `Authorization: Bearer <token>`; reads (the scene's websocket
  is one: it shows the scene and changes nothing on the desk) may instead carry the read cookie the desk sets
  on an answer to a request with the token (so the page's images, server-sent events and the scene's iframe
  and websocket, which cannot send headers, work), and the scene's page may carry the token as `?token=`.
  The cookie is a random key of this server process, not the token, and never authorizes a change, so a
  cross-site request cannot ride on it.
- The token is made at the first start off loopback (`secrets.token_urlsafe`), shown once, and stored
  only as a salted SHA-256 digest in DATA/access-token.json (mode 600). A slow hash (scrypt) protects
  guessable passwords; a 256-bit random token is not guessable, and a fast digest keeps every request
  cheap. `calib serve --new-token` replaces a lost token.
- A request that changes state and carries an Origin header other than the desk's own is refused (403),
  on loopback too: a page on another site cannot drive the robot through the operator's browser. So is a
  websocket from another site's page (browsers let any page open one, with the desk's cookies). On
  loopback, `calib serve` also answers only to loopback host names (a DNS-rebinding page's Host is its
  own name), the websocket included. A refused websocket gets the HTTP answer instead of the upgrade (or,
  where the server cannot send one, a close with code 1008, policy violation).
- No page of another site may frame the desk's page or its API (X-Frame-Options and the CSP's
  frame-ancestors: a click in an invisible frame could start a motion); the scene may be framed by the
  desk's own page only. Off loopback the OpenAPI document and its page (/openapi.json, /docs) need the token
  too (the page, opened by address, may carry it as `?token=`).
- Request bodies are capped before they are read: an upload (a CSV to import, a robot's profile with its
  URDF) at the desk's upload limit plus the form's overhead, a session's images (a hand-eye import) at what a
  zip may unpack to, anything else at MAX_BODY_BYTES; a declared
  Content-Length above the cap is refused at once, and a body streamed without one is cut off when it
  passes the cap (413 either way).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import os
import re
import secrets
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException

from .limits import Limits

TOKEN_FILE = "access-token.json"
TOKEN_FORMAT = "calib-access-token/1"
READ_COOKIE = "calib_read"
OPEN_PATHS = frozenset({"/api/health"})
GUARDED_PREFIXES = ("/api", "/scene", "/docs", "/openapi.json")
PAGES_WITH_TOKEN = ("/scene", "/docs")  # pages a browser opens by address: the token may come as ?token=
SAFE_METHODS = frozenset({"GET", "HEAD"})
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
MAX_BODY_BYTES = 1024 * 1024
FORM_OVERHEAD_BYTES = 64 * 1024
UPLOAD_PATHS = frozenset({"/api/sessions/import", "/api/robots"})
IMAGES_PATHS = frozenset({"/api/sessions/import-handeye"})  # a session's images: as much together as a zip unpacks to
# No page of another site may frame the desk (a click in a hidden frame could start a motion): the page and the
# API never, the scene only inside the desk's own page (its iframe).
NO_FRAMING = ((b"x-frame-options", b"DENY"), (b"content-security-policy", b"frame-ancestors 'none'"))
SCENE_FRAMING = ((b"x-frame-options", b"SAMEORIGIN"), (b"content-security-policy", b"frame-ancestors 'self'"))

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]
Refusal = tuple[int, str, list[tuple[bytes, bytes]]]  # status, detail, extra headers


def is_loopback(host: str) -> bool:
    """True for an address only this machine reaches (127.0.0.0/8, ::1, localhost)."""
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class TokenFile:
    """The access token's salted digest in the data directory; the token itself is never stored."""

    def __init__(self, data_dir: Path) -> None:
        self.path = Path(data_dir) / TOKEN_FILE
        self._digest: bytes | None = None
        self._salt = b""

    def ensure(self) -> str | None:
        """Make a token if none is stored and return it (shown once); None when one exists."""
        if self.path.is_file():
            self._load()
            return None
        return self.renew()

    def renew(self) -> str:
        """A new token replaces the old one; returns it."""
        token = secrets.token_urlsafe(32)
        salt = secrets.token_bytes(16)
        record = {"format": TOKEN_FORMAT, "hash": "sha256", "salt": salt.hex(), "digest": _digest(salt, token).hex()}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.{secrets.token_hex(4)}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w") as f:
                json.dump(record, f)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o600)
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        self._salt, self._digest = salt, _digest(salt, token)
        return token

    def verify(self, token: str) -> bool:
        if self._digest is None:
            self._load()
        assert self._digest is not None
        return hmac.compare_digest(_digest(self._salt, token), self._digest)

    def _load(self) -> None:
        if self.path.stat().st_mode & 0o077:
            os.chmod(self.path, 0o600)
        record = json.loads(self.path.read_text())
        if record.get("format") != TOKEN_FORMAT or record.get("hash") != "sha256":
            raise ValueError(f"{self.path.name}: not a {TOKEN_FORMAT} file")
        self._salt, self._digest = bytes.fromhex(record["salt"]), bytes.fromhex(record["digest"])


def _digest(salt: bytes, token: str) -> bytes:
    return hashlib.sha256(salt + token.encode()).digest()


class BodyTooLarge(HTTPException):
    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {_size(limit)}")


class Guard:
    """ASGI middleware in front of the app: host names, cross-origin changes, the token, body size."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        tokens: TokenFile | None,
        trusted_hosts: Iterable[str] | None = None,
        limits: Limits | None = None,
    ) -> None:
        self.app = app
        self.tokens = tokens
        self.trusted_hosts = None if trusted_hosts is None else frozenset(h.lower() for h in trusted_hosts)
        limits = limits or Limits()
        self.caps = {path: limits.upload_bytes + FORM_OVERHEAD_BYTES for path in UPLOAD_PATHS} | {
            path: limits.unpacked_bytes + FORM_OVERHEAD_BYTES for path in IMAGES_PATHS
        }
        self.read_key = secrets.token_urlsafe(32)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        websocket = scope["type"] == "websocket"
        headers = Headers(scope=scope)
        refusal, set_cookie = self._check(scope, headers, websocket)
        if refusal is not None:
            await (_refuse_websocket(scope, receive, send, *refusal) if websocket else _answer(send, *refusal))
            return
        if websocket:
            await self.app(scope, receive, send)
            return
        path = scope["path"]
        limit = self.caps.get(path, MAX_BODY_BYTES)
        declared = headers.get("content-length")
        if declared is not None:
            if not declared.isdigit():
                await _answer(send, 400, "Content-Length is not a number")
                return
            if int(declared) > limit:
                await _answer(send, 413, f"request body larger than {_size(limit)}")
                return
        received = 0
        started = False

        async def capped_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(limit)
            return message

        framing = SCENE_FRAMING if path.startswith("/scene") else NO_FRAMING

        async def send_with_cookie(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message["headers"] = [*message.get("headers", []), *framing]
                if set_cookie:
                    cookie = f"{READ_COOKIE}={self.read_key}; Path=/; HttpOnly; SameSite=Strict"
                    message["headers"].append((b"set-cookie", cookie.encode()))
            await send(message)

        try:
            await self.app(scope, capped_receive, send_with_cookie)
        except BodyTooLarge as exc:
            if started:
                raise
            await _answer(send, 413, str(exc.detail))

    def _check(self, scope: Scope, headers: Headers, websocket: bool) -> tuple[Refusal | None, bool]:
        """(why the request is refused, or None; whether the answer sets the read cookie)."""
        method, path = ("GET" if websocket else scope["method"]), scope["path"]
        host = headers.get("host", "")
        if self.trusted_hosts is not None and _hostname(host) not in self.trusted_hosts:
            return (403, f"this desk answers only to {', '.join(sorted(self.trusted_hosts))}", []), False
        origin = headers.get("origin")
        scheme = {"ws": "http", "wss": "https"}.get(scope["scheme"], scope["scheme"])
        if (
            (websocket or method not in SAFE_METHODS)
            and origin is not None
            and origin.lower() != f"{scheme}://{host}".lower()
        ):
            what = "open the desk's scene" if websocket else "change anything here"
            return (403, f"a request from another site's page may not {what}", []), False
        if self.tokens is None or not path.startswith(GUARDED_PREFIXES) or path in OPEN_PATHS:
            return None, False
        token = _bearer(headers.get("authorization", ""))
        if token is None and path.startswith(PAGES_WITH_TOKEN) and method in SAFE_METHODS:
            token = next(iter(parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [])), None)
        if token is not None and self.tokens.verify(token):
            return None, not websocket and _cookie(headers, READ_COOKIE) != self.read_key
        if method in SAFE_METHODS and hmac.compare_digest(_cookie(headers, READ_COOKIE) or "", self.read_key):
            return None, False
        what = "a wrong access token" if token is not None else "no access token"
        detail = (
            f"this desk is reachable from the network and the request has {what}: send "
            "'Authorization: Bearer <token>' with the token calib serve printed at its first start"
        )
        return (401, detail, [(b"www-authenticate", b"Bearer")]), False


def _hostname(host: str) -> str:
    """The name of a Host header without its port ("[::1]:8000" -> "::1")."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _bearer(authorization: str) -> str | None:
    scheme, _, value = authorization.partition(" ")
    return value.strip() if scheme.lower() == "bearer" and value.strip() else None


def _cookie(headers: Headers, name: str) -> str | None:
    for part in headers.get("cookie", "").split(";"):
        key, _, value = part.strip().partition("=")
        if key == name:
            return value
    return None


def _size(n: int) -> str:
    return f"{n / (1024 * 1024):.1f} MB" if n >= 1024 * 1024 else f"{n // 1024} kB"


async def _answer(send: Send, status: int, detail: str, extra: list[tuple[bytes, bytes]] | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": headers + (extra or [])})
    await send({"type": "http.response.body", "body": body})


async def _refuse_websocket(
    scope: Scope, receive: Receive, send: Send, status: int, detail: str, extra: list[tuple[bytes, bytes]]
) -> None:
    """Refuse a websocket before it opens: the HTTP answer where the server can send one (ASGI's
    websocket.http.response), else a close with 1008 (policy violation)."""
    await receive()  # websocket.connect
    if "websocket.http.response" not in scope.get("extensions", {}):
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
        return
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), *extra]
    await send({"type": "websocket.http.response.start", "status": status, "headers": headers})
    await send({"type": "websocket.http.response.body", "body": body})


class Scrubber:
    """Error texts without the server's own paths: any path under one of `roots` becomes its file name."""

    def __init__(self, roots: Iterable[Path]) -> None:
        names = {str(r) for root in roots for r in (Path(root), Path(root).resolve()) if r.is_absolute()} - {"/"}
        alternatives = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
        end = r"[\s'\":,;()]"
        self._pattern = re.compile(rf"(?:{alternatives})(?={end}|/|$)[^\s'\":,;()]*") if alternatives else None

    def __call__(self, text: str) -> str:
        if self._pattern is None:
            return text
        return self._pattern.sub(lambda m: Path(m.group()).name or "<data>", text)
