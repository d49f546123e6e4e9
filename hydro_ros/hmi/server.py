"""The HMI's web server (aiohttp): one page, a websocket of decimated updates, two operator actions.

Security by default, because the page can reach a machine that moves:
- read-only unless an operator token is configured; an action needs ``Authorization: Bearer <token>``,
  compared in constant time; every attempt, refused or accepted, is logged with the client address;
- a browser request from another origin is refused (no CORS headers at all, and the Origin header
  of actions and of the websocket handshake must be this server), so another site open in the
  operator's browser cannot act through it;
- inputs are validated: small JSON bodies only, a path and method must be in the served catalog;
- a Content-Security-Policy that allows this origin's scripts and nothing else;
- the Host header must name this server (loopback names, the configured host, ``allowed_hosts``), so a
  hostile site whose DNS name is re-bound to this address cannot read the machine's state;
- what a request without the token can put on the page or in the log is clipped and printable, and
  kept apart from the operator's actions (bounded, repeats counted, never pushing actions out);
- failed token attempts slow the checks down: past ``TOKEN_FAILURES`` wrong tokens in ``TOKEN_WINDOW_S`` from one
  address, or ``GLOBAL_TOKEN_FAILURES`` from all of them (a guesser rotating its source addresses), every check waits
  ``TARPIT_S`` and they run one at a time, so the server answers at most one guess per ``TARPIT_S`` from anywhere;
  the right token is still checked and accepted, never refused, so a guesser cannot lock the operator out; every
  refusal is counted for the node's /diagnostics, and malformed requests the HTTP parser rejects are logged once per
  ``QUIET_LOG_S`` with their count, never a traceback each.
Binding to localhost is the node's default (parameter ``host``).
"""

from __future__ import annotations

import asyncio
import collections
import hmac
import json
import logging
import math
import re
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

from aiohttp import ClientSession, WSMsgType, web

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.alarm_log import read_events
from hydro_ros.hmi.state import HmiState, clip

MAX_BODY_BYTES = 1024
MAX_WEBSOCKETS = 16
IDENTIFIER = re.compile(r"[A-Za-z0-9_\-]{1,64}")
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
                               "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
ALARM_PAGE_MAX = 100
TOKEN_FAILURES = 5  # wrong tokens an address may send per window before its checks are slowed
GLOBAL_TOKEN_FAILURES = 20  # ... and from all addresses together
TOKEN_WINDOW_S = 10.0
TARPIT_S = 1.0  # [s] each token check waits this long, one at a time, while the server is being guessed
QUIET_LOG_S = 60.0
STATIC_DIR = Path(str(resources.files("hydro_ros.hmi") / "static"))
STATE_KEY = web.AppKey("state", HmiState)
SETTINGS_KEY = web.AppKey("settings", dict)


@dataclass
class Guard:
    """The server's refusals, counted for /diagnostics, and the per-client memory of failed tokens."""

    allowed_hosts: frozenset[str]
    counts: collections.Counter = field(default_factory=collections.Counter)
    failures: dict[str, collections.deque] = field(default_factory=dict)
    recent: collections.deque = field(default_factory=lambda: collections.deque(maxlen=GLOBAL_TOKEN_FAILURES))
    clock: Callable[[], float] = time.monotonic
    tarpit_s: float = TARPIT_S
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)

    def host_allowed(self, host_header: str) -> bool:
        if host_header.startswith("["):  # [::1]:8080
            host = host_header[1:host_header.find("]")] if "]" in host_header else ""
        else:
            host = host_header.rsplit(":", 1)[0] if host_header.count(":") == 1 else host_header
        return host.lower() in self.allowed_hosts

    def wait_s(self, client: str) -> float:
        """Seconds until ``client`` may try a token again (0: now)."""
        recent = self.failures.get(client)
        if recent is None:
            return 0.0
        while recent and self.clock() - recent[0] > TOKEN_WINDOW_S:
            recent.popleft()
        if not recent:
            del self.failures[client]
            return 0.0
        return TOKEN_WINDOW_S - (self.clock() - recent[0]) if len(recent) >= TOKEN_FAILURES else 0.0

    def guessed(self) -> bool:
        """Whether the server as a whole is being guessed at (GLOBAL_TOKEN_FAILURES within the window)."""
        return len(self.recent) >= GLOBAL_TOKEN_FAILURES and self.clock() - self.recent[0] <= TOKEN_WINDOW_S

    def failed(self, client: str) -> None:
        if len(self.failures) > 10_000:  # a flood of fresh addresses must not grow the memory without bound
            self.failures.clear()
        self.failures.setdefault(client, collections.deque(maxlen=TOKEN_FAILURES)).append(self.clock())
        self.recent.append(self.clock())
        self.counts["token_failures"] += 1


GUARD_KEY = web.AppKey("guard", Guard)


class QuietBadRequests(logging.Filter):
    """aiohttp logs each request its parser rejects (control characters in a header) with a traceback: a flood of them
    would fill the node's log. One line per QUIET_LOG_S with the count instead."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.clock = clock
        self.since = -math.inf
        self.dropped = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.ERROR and not record.exc_info:
            return True
        now = self.clock()
        if now - self.since < QUIET_LOG_S:
            self.dropped += 1
            return False
        error = record.exc_info[1] if record.exc_info else None
        record.msg = (f"malformed request refused ({type(error).__name__ if error else record.getMessage()[:80]}); "
                      f"{self.dropped} more since the last such line")
        record.args, record.exc_info, record.exc_text = (), None, None
        self.since, self.dropped = now, 0
        return True


class OperatorActions(Protocol):
    """What an accepted action does on the machine; the node implements it with a service and a topic."""

    async def acknowledge(self) -> tuple[bool, str]: ...

    async def request_path(self, path: str, method: str) -> tuple[bool, str]: ...


def create_app(state: HmiState, actions: OperatorActions, *, token: str, update_period_s: float,
               log: Callable[[str], None], allowed_hosts: frozenset[str] = LOOPBACK_NAMES,
               alarm_log: Path | None = None) -> web.Application:
    """``allowed_hosts``: the names the Host header may carry (without port); loopback names are always in.
    ``alarm_log``: fdi_node's alarm log, shown paged (read-only)."""
    if not update_period_s > 0:
        raise InputError(f"HMI update period {update_period_s}: must be > 0")
    app = web.Application(client_max_size=MAX_BODY_BYTES, middlewares=[_host_check])
    app[GUARD_KEY] = Guard(frozenset(name.strip("[]").lower() for name in allowed_hosts) | LOOPBACK_NAMES)
    app[STATE_KEY] = state
    app[SETTINGS_KEY] = {"token": token, "period": update_period_s, "log": log, "actions": actions, "sockets": set(),
                         "alarm_log": alarm_log}
    app.on_response_prepare.append(_security_headers)
    app.on_shutdown.append(_close_websockets)
    app.router.add_get("/", _index)
    app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False, show_index=False)
    app.router.add_get("/api/state", _state)
    app.router.add_get("/ws", _websocket)
    app.router.add_get("/api/alarm_log", _alarm_log)
    app.router.add_post("/api/acknowledge", _acknowledge)
    app.router.add_post("/api/request", _request_path)
    return app


@web.middleware
async def _host_check(request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]) -> web.StreamResponse:
    guard = request.app[GUARD_KEY]
    if not guard.host_allowed(request.host):
        guard.counts["refused_hosts"] += 1
        raise _error(web.HTTPMisdirectedRequest, f"host {clip(request.host, 64)!r} is not served here")
    return await handler(request)


async def _security_headers(_request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(SECURITY_HEADERS)


async def _close_websockets(app: web.Application) -> None:
    for ws in list(app[SETTINGS_KEY]["sockets"]):
        await ws.close(code=1001, message=b"server shutting down")


def _same_origin(request: web.Request) -> bool:
    """Browsers send Origin on cross-site requests and websocket handshakes; non-browser clients may omit it."""
    origin = request.headers.get("Origin")
    return origin is None or origin == f"{request.scheme}://{request.host}"


def _error(status: type[web.HTTPException], message: str) -> web.HTTPException:
    return status(text=json.dumps({"ok": False, "error": message}), content_type="application/json")


async def _index(request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC_DIR / "index.html")


async def _state(request: web.Request) -> web.Response:
    view, _ = request.app[STATE_KEY].snapshot()
    return web.json_response(_with_settings(request.app, view))


def _with_settings(app: web.Application, view: dict[str, Any]) -> dict[str, Any]:
    settings = app[SETTINGS_KEY]
    view["actions_enabled"] = bool(settings["token"])
    return view


async def _alarm_log(request: web.Request) -> web.Response:
    """One page of the alarm log, newest first: ``?offset=N&limit=M`` (M at most ALARM_PAGE_MAX)."""
    path = request.app[SETTINGS_KEY]["alarm_log"]
    if path is None:
        raise _error(web.HTTPNotFound, "no alarm log configured (hmi parameter alarm_log)")
    try:
        offset = int(request.query.get("offset", "0"))
        limit = int(request.query.get("limit", "20"))
    except ValueError:
        raise _error(web.HTTPBadRequest, "offset and limit: expected integers") from None
    if not (offset >= 0 and 1 <= limit <= ALARM_PAGE_MAX):
        raise _error(web.HTTPBadRequest, f"offset >= 0 and 1 <= limit <= {ALARM_PAGE_MAX}")
    try:
        events, total = await asyncio.to_thread(read_events, path, offset=offset, limit=limit)
    except InputError as exc:
        raise _error(web.HTTPServiceUnavailable, str(exc)) from None
    return web.json_response({"total": total, "offset": offset, "events": events})


async def _websocket(request: web.Request) -> web.WebSocketResponse:
    settings = request.app[SETTINGS_KEY]
    if not _same_origin(request):
        request.app[GUARD_KEY].counts["refused_origins"] += 1
        raise _error(web.HTTPForbidden, f"websocket from origin {clip(request.headers.get('Origin', ''), 64)!r} refused")
    if len(settings["sockets"]) >= MAX_WEBSOCKETS:
        raise _error(web.HTTPServiceUnavailable, f"too many HMI clients (at most {MAX_WEBSOCKETS})")
    ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=MAX_BODY_BYTES)
    await ws.prepare(request)
    settings["sockets"].add(ws)
    state: HmiState = request.app[STATE_KEY]
    sender = asyncio.create_task(_push_updates(ws, state, request.app))
    try:
        async for message in ws:  # the page sends nothing; this waits for the close
            if message.type == WSMsgType.ERROR:
                break
    finally:
        sender.cancel()
        settings["sockets"].discard(ws)
    return ws


async def _push_updates(ws: web.WebSocketResponse, state: HmiState, app: web.Application) -> None:
    """A snapshot, then at most one update per period: the browser draws at the rate it is sent."""
    view, cursor = state.snapshot()
    period = app[SETTINGS_KEY]["period"]
    try:
        await ws.send_str(json.dumps(dict(_with_settings(app, view), type="snapshot")))
        while not ws.closed:
            await asyncio.sleep(period)
            view, cursor = state.update(cursor)
            await ws.send_str(json.dumps(dict(_with_settings(app, view), type="update")))
    except ConnectionError:  # the page went away between two updates
        return


class _TooLarge(web.HTTPClientError):
    status_code = 413  # aiohttp's own HTTPRequestEntityTooLarge takes sizes, not a message


Refuse = Callable[[type[web.HTTPException], str], web.HTTPException]


def _refuser(request: web.Request, action: str, *, authenticated: bool = True) -> Refuse:
    """The HTTP error for a refused action, logged (clipped) and listed on the page."""
    settings = request.app[SETTINGS_KEY]
    client = request.remote or "unknown"

    def refuse(status: type[web.HTTPException], reason: str) -> web.HTTPException:
        reason = clip(reason)
        request.app[GUARD_KEY].counts["refused_requests"] += 1
        settings["log"](f"operator action {action} from {client} refused: {reason}")
        request.app[STATE_KEY].record_action(action, False, reason, client, authenticated=authenticated)
        return _error(status, reason)

    return refuse


async def _authorised_body(request: web.Request, action: str) -> tuple[dict[str, Any], Refuse]:
    """The JSON body of an action from a same-origin client holding the token, and the refuser for what
    follows; or an HTTP error."""
    settings = request.app[SETTINGS_KEY]
    guard = request.app[GUARD_KEY]
    refuse = _refuser(request, action, authenticated=False)
    client = request.remote or "unknown"
    if not _same_origin(request):
        guard.counts["refused_origins"] += 1
        raise refuse(web.HTTPForbidden, f"cross-origin request from {request.headers.get('Origin')!r}")
    if not settings["token"]:
        raise refuse(web.HTTPForbidden, "read-only HMI: no operator token is configured (parameter operator_token or "
                                        "HYDRO_ROS_HMI_TOKEN)")
    supplied = request.headers.get("Authorization", "")
    if not supplied.startswith("Bearer ") or not supplied[len("Bearer "):]:
        raise refuse(web.HTTPUnauthorized, "operator token required")
    if guard.wait_s(client) > 0 or guard.guessed():
        # slowed, not refused: one check per tarpit_s from anywhere, and the right token still gets in
        guard.counts["rate_limited"] += 1
        async with guard.lock:
            await asyncio.sleep(guard.tarpit_s)
            right = hmac.compare_digest(supplied[len("Bearer "):].encode(), settings["token"].encode())
    else:
        right = hmac.compare_digest(supplied[len("Bearer "):].encode(), settings["token"].encode())
    if not right:
        guard.failed(client)
        raise refuse(web.HTTPUnauthorized, "operator token rejected")
    refuse = _refuser(request, action)
    if request.content_type != "application/json":
        raise refuse(web.HTTPUnsupportedMediaType, f"content type {request.content_type!r}: expected application/json")
    try:
        body = await request.json()
    except web.HTTPRequestEntityTooLarge:
        raise refuse(_TooLarge, f"body larger than {MAX_BODY_BYTES} bytes") from None
    except ValueError:
        raise refuse(web.HTTPBadRequest, "body: not JSON") from None
    if not isinstance(body, dict):
        raise refuse(web.HTTPBadRequest, "body: expected a JSON object")
    return body, refuse


async def _acknowledge(request: web.Request) -> web.Response:
    await _authorised_body(request, "acknowledge")
    state: HmiState = request.app[STATE_KEY]
    shown = state.unacknowledged()
    return await _perform(request, "acknowledge", request.app[SETTINGS_KEY]["actions"].acknowledge(),
                          on_success=lambda: state.mark_acknowledged(shown))


async def _request_path(request: web.Request) -> web.Response:
    body, refuse = await _authorised_body(request, "request_path")
    path, method = body.get("path"), body.get("method")
    for name, value in (("path", path), ("method", method)):
        if not isinstance(value, str) or not IDENTIFIER.fullmatch(value):
            raise refuse(web.HTTPBadRequest, f"{name} {str(value)[:40]!r}: expected an identifier ([A-Za-z0-9_-], at most 64)")
    state: HmiState = request.app[STATE_KEY]
    if state.halt:
        raise refuse(web.HTTPConflict, "the FDI node requests a halt (severe fault): no motion is requested while it stands")
    methods = state.catalog_methods(path)
    if methods is None:
        raise refuse(web.HTTPBadRequest, f"path {path!r}: not in the trajectory catalog")
    if method not in methods:
        raise refuse(web.HTTPBadRequest, f"method {method!r}: not stored for path {path!r} (stored: {', '.join(methods) or 'none'})")
    return await _perform(request, f"request_path {path} {method}", request.app[SETTINGS_KEY]["actions"].request_path(path, method))


async def _perform(request: web.Request, action: str, outcome: Awaitable[tuple[bool, str]], on_success: Callable[[], Any] = lambda: None) -> web.Response:
    settings = request.app[SETTINGS_KEY]
    client = request.remote or "unknown"
    ok, detail = await outcome
    settings["log"](f"operator action {action} from {client}: {'done' if ok else 'failed'}: {detail}")
    if ok:
        on_success()
    request.app[STATE_KEY].record_action(action, ok, detail, client)
    return web.json_response({"ok": ok, "detail" if ok else "error": detail}, status=200 if ok else 502)


FOXGLOVE_PROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
MAX_FOXGLOVE_CLIENTS = 8


def foxglove_gate(upstream_port: int, *, allowed_hosts: frozenset[str] = LOOPBACK_NAMES,
                  allowed_origins: frozenset[str] = frozenset()) -> web.Application:
    """The door of the read-only Foxglove server (foxglove-sdk, listening on loopback at ``upstream_port``): the same Host
    check as the page (DNS rebinding), an Origin allow-list (clients without an Origin, such as the desktop app, and
    loopback origins, plus ``allowed_origins``), and at most MAX_FOXGLOVE_CLIENTS at once; an admitted client's frames are
    relayed both ways unchanged (the server itself refuses a client that tries to publish)."""
    app = web.Application(middlewares=[_host_check])
    guard = app[GUARD_KEY] = Guard(frozenset(name.strip("[]").lower() for name in allowed_hosts) | LOOPBACK_NAMES)
    clients: set[web.WebSocketResponse] = set()

    def origin_allowed(origin: str) -> bool:
        from urllib.parse import urlsplit

        return origin.lower() in allowed_origins or (urlsplit(origin).hostname or "").lower() in LOOPBACK_NAMES

    async def relay(request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin is not None and not origin_allowed(origin):
            guard.counts["refused_origins"] += 1
            raise _error(web.HTTPForbidden, f"origin {clip(origin, 64)!r} may not connect")
        if len(clients) >= MAX_FOXGLOVE_CLIENTS:
            guard.counts["refused_connections"] += 1
            raise _error(web.HTTPServiceUnavailable, f"{MAX_FOXGLOVE_CLIENTS} Foxglove clients connected already")
        ws = web.WebSocketResponse(protocols=FOXGLOVE_PROTOCOLS, max_msg_size=MAX_BODY_BYTES * 64)
        await ws.prepare(request)
        clients.add(ws)
        try:
            async with ClientSession() as session, session.ws_connect(
                    f"http://127.0.0.1:{upstream_port}/", protocols=[ws.ws_protocol or FOXGLOVE_PROTOCOLS[0]], max_msg_size=0) as upstream:
                async def pump(source: Any, sink: Any) -> None:
                    async for message in source:
                        if message.type == WSMsgType.TEXT:
                            await sink.send_str(message.data)
                        elif message.type == WSMsgType.BINARY:
                            await sink.send_bytes(message.data)
                        else:
                            break

                tasks = [asyncio.ensure_future(pump(upstream, ws)), asyncio.ensure_future(pump(ws, upstream))]
                _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                for task in pending:
                    task.cancel()
        except OSError:
            pass  # the upstream server is gone (the node stopping): the client's socket closes below
        finally:
            clients.discard(ws)
            await ws.close()
        return ws

    app.router.add_get("/", relay)
    return app
