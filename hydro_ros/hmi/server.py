"""The HMI's web server (aiohttp): one page, a websocket of decimated updates, two operator actions.

Security by default, because the page can reach a machine that moves:
- read-only unless an operator token is configured; an action needs ``Authorization: Bearer <token>``,
  compared in constant time; every attempt, refused or accepted, is logged with the client address;
- a browser request from another origin is refused (no CORS headers at all, and the Origin header
  of actions and of the websocket handshake must be this server), so another site open in the
  operator's browser cannot act through it;
- inputs are validated: small JSON bodies only, a path and method must be in the served catalog;
- a Content-Security-Policy that allows this origin's scripts and nothing else.
Binding to localhost is the node's default (parameter ``host``).
"""

from __future__ import annotations

import asyncio
import hmac
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any, Awaitable, Callable, Protocol

from aiohttp import WSMsgType, web

from hydro_ros.contract.errors import InputError
from hydro_ros.hmi.state import HmiState

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
STATIC_DIR = Path(str(resources.files("hydro_ros.hmi") / "static"))
STATE_KEY = web.AppKey("state", HmiState)
SETTINGS_KEY = web.AppKey("settings", dict)


class OperatorActions(Protocol):
    """What an accepted action does on the machine; the node implements it with a service and a topic."""

    async def acknowledge(self) -> tuple[bool, str]: ...

    async def request_path(self, path: str, method: str) -> tuple[bool, str]: ...


def create_app(state: HmiState, actions: OperatorActions, *, token: str, update_period_s: float,
               log: Callable[[str], None]) -> web.Application:
    if not update_period_s > 0:
        raise InputError(f"HMI update period {update_period_s}: must be > 0")
    app = web.Application(client_max_size=MAX_BODY_BYTES)
    app[STATE_KEY] = state
    app[SETTINGS_KEY] = {"token": token, "period": update_period_s, "log": log, "actions": actions, "sockets": set()}
    app.on_response_prepare.append(_security_headers)
    app.on_shutdown.append(_close_websockets)
    app.router.add_get("/", _index)
    app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False, show_index=False)
    app.router.add_get("/api/state", _state)
    app.router.add_get("/ws", _websocket)
    app.router.add_post("/api/acknowledge", _acknowledge)
    app.router.add_post("/api/request", _request_path)
    return app


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


async def _websocket(request: web.Request) -> web.WebSocketResponse:
    settings = request.app[SETTINGS_KEY]
    if not _same_origin(request):
        raise _error(web.HTTPForbidden, f"websocket from origin {request.headers.get('Origin')!r} refused")
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


def _refuser(request: web.Request, action: str) -> Refuse:
    """The HTTP error for a refused action, logged and listed on the page first."""
    settings = request.app[SETTINGS_KEY]
    client = request.remote or "unknown"

    def refuse(status: type[web.HTTPException], reason: str) -> web.HTTPException:
        settings["log"](f"operator action {action} from {client} refused: {reason}")
        request.app[STATE_KEY].record_action(action, False, reason, client)
        return _error(status, reason)

    return refuse


async def _authorised_body(request: web.Request, refuse: Refuse) -> dict[str, Any]:
    """The JSON body of an action from a same-origin client holding the token, or an HTTP error."""
    settings = request.app[SETTINGS_KEY]
    if not _same_origin(request):
        raise refuse(web.HTTPForbidden, f"cross-origin request from {request.headers.get('Origin')!r}")
    if not settings["token"]:
        raise refuse(web.HTTPForbidden, "read-only HMI: no operator token is configured (parameter operator_token or "
                                        "HYDRO_ROS_HMI_TOKEN)")
    supplied = request.headers.get("Authorization", "")
    if not supplied.startswith("Bearer ") or not supplied[len("Bearer "):]:
        raise refuse(web.HTTPUnauthorized, "operator token required")
    if not hmac.compare_digest(supplied[len("Bearer "):].encode(), settings["token"].encode()):
        raise refuse(web.HTTPUnauthorized, "operator token rejected")
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
    return body


async def _acknowledge(request: web.Request) -> web.Response:
    await _authorised_body(request, _refuser(request, "acknowledge"))
    state: HmiState = request.app[STATE_KEY]
    shown = state.unacknowledged()
    return await _perform(request, "acknowledge", request.app[SETTINGS_KEY]["actions"].acknowledge(),
                          on_success=lambda: state.mark_acknowledged(shown))


async def _request_path(request: web.Request) -> web.Response:
    refuse = _refuser(request, "request_path")
    body = await _authorised_body(request, refuse)
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
