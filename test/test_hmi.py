"""The HMI's state model and web server without ROS: alarms, staleness, decimation, and the security rules."""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import time
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from hydro_ros.hmi.server import GLOBAL_TOKEN_FAILURES, GUARD_KEY, MAX_BODY_BYTES, TOKEN_FAILURES, TOKEN_WINDOW_S, create_app
from hydro_ros.hmi.state import MAX_ACTIONS, MAX_DETAIL_CHARS, MAX_REFUSALS, HmiState, StatusReport

TOKEN = "s3cret-operator-token"


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _status(level: int, message: str, actuator: str = "boom", detected: str = "") -> StatusReport:
    return StatusReport(f"hydro_ros/fdi/{actuator}", level, message, "sam",
                        {"pattern": "0100", "method": "ukf", "first_detection_stamp_s": detected, "samples": "5"})


def test_an_alarm_is_raised_refined_acknowledged_and_cleared_once():
    clock = FakeClock()
    state = HmiState(clock=clock)
    state.on_diagnostics(1.0, [_status(0, "ok"), StatusReport("hydro_ros/plant_sim", 0, "ok", "sam", {}),
                               StatusReport("hydro_ros/fdi/self_test/weights", 2, "failed", "sam", {})])
    view, _ = state.snapshot()
    assert [t["actuator"] for t in view["tiles"]] == ["boom"] and view["alarms"] == []
    clock.now += 5
    state.on_diagnostics(6.0, [_status(1, "unisolated", detected="5.5")])
    clock.now += 2
    state.on_diagnostics(8.0, [_status(1, "external_leakage_a", detected="5.5")])
    view, _ = state.snapshot()
    tile = view["tiles"][0]
    assert (tile["level"], tile["fault"], tile["since_wall"], tile["detected_stamp_s"]) == ("WARN", "external_leakage_a", 1007.0, 5.5)
    assert tile["values"] == {"pattern": "0100", "method": "ukf", "first_detection_stamp_s": "5.5"}  # counters stay off the tile
    [alarm] = view["alarms"]  # isolation refined the alarm raised at the first detection, it did not add one
    assert (alarm["fault"], alarm["raised_wall"], alarm["active"]) == ("external_leakage_a", 1005.0, True)
    clock.now += 1
    shown = state.unacknowledged()
    state.on_diagnostics(10.0, [_status(0, "ok")])  # the FDI node clears the latch before its service answers
    assert state.mark_acknowledged(shown) == 1 and state.mark_acknowledged(shown) == 0 and state.unacknowledged() == []
    state.on_diagnostics(11.0, [_status(1, "external_leakage_b")])  # a new fault is a new alarm
    view, _ = state.snapshot()
    newest, old = view["alarms"]
    assert (old["acknowledged_wall"], old["cleared_wall"], old["active"]) == (1008.0, 1008.0, False)
    assert newest["fault"] == "external_leakage_b" and newest["id"] == old["id"] + 1 and newest["acknowledged_wall"] is None


def test_a_silent_fdi_node_turns_its_tiles_stale():
    clock = FakeClock()
    state = HmiState(stale_timeout_s=3.0, clock=clock)
    state.expect("sam", ["boom", "stick"])
    assert [(t["actuator"], t["level"], t["fault"]) for t in state.snapshot()[0]["tiles"]] == [
        ("boom", "STALE", "waiting for /diagnostics"), ("stick", "STALE", "waiting for /diagnostics")]
    state.on_diagnostics(1.0, [_status(1, "external_leakage_a")])
    assert state.snapshot()[0]["alarms"][0]["actuator"] == "boom"
    clock.now += 2.5
    assert state.snapshot()[0]["tiles"][0]["level"] == "WARN"
    clock.now += 1.0
    boom, stick = state.snapshot()[0]["tiles"]
    assert boom["level"] == "STALE" and boom["fault"] == "no /diagnostics for 4 s"
    assert stick["fault"] == "waiting for /diagnostics"


def test_residuals_are_decimated_windowed_and_sent_once():
    state = HmiState(plot_window_s=60.0, plot_period_s=0.1)
    names = ["boom/mean_r_pA", "boom/threshold_pA", "boom/mean_r_pB", "boom/threshold_pB"]
    for k in range(5000):  # 100 s at the fdi_node's 50 Hz
        state.on_residuals(k * 0.02, names, [0.001 * k, 0.05, math.nan if k == 4999 else -0.001, 0.05])
    view, cursor = state.snapshot()
    rows = view["residuals"]["rows"]
    stamps = [row[0] for row in rows]
    assert min(b - a for a, b in itertools.pairwise(stamps)) >= 0.1 - 1e-9
    assert stamps[-1] - stamps[0] <= 60.0 and len(rows) in range(500, 602)
    assert rows[-1][3] is None  # NaN travels as a gap, JSON has no NaN
    json.dumps(view, allow_nan=False)
    view, cursor2 = state.update(cursor)
    assert view["residuals"]["rows"] == [] and not view["residuals"]["reset"] and cursor2 == cursor
    state.on_residuals(100.1, names, [1.0, 0.05, 0.0, 0.05])
    view, cursor3 = state.update(cursor2)
    assert [row[0] for row in view["residuals"]["rows"]] == [100.1] and not view["residuals"]["reset"]
    state.on_residuals(3.0, names, [1.0, 0.05, 0.0, 0.05])  # time ran backwards: a replay restarted
    view, _ = state.update(cursor3)
    assert view["residuals"]["reset"] and [row[0] for row in view["residuals"]["rows"]] == [3.0]


def test_catalog_errors_keep_the_last_good_catalog():
    state = HmiState()
    state.on_catalog(json.dumps([{"path": "horizontal", "solutions": {"dp_cp": {}, "pinv_joint": {}}}]))
    state.on_catalog("{not json")
    view, _ = state.snapshot()
    assert view["catalog"][0]["path"] == "horizontal" and view["catalog_error"].startswith("catalog: malformed")
    assert state.catalog_methods("horizontal") == ["dp_cp", "pinv_joint"] and state.catalog_methods("vertical") is None
    state.on_result("[1, 2]")
    assert state.snapshot()[0]["result"]["ok"] is False
    # a peer's NaN (JSON NaN, a NaN joint reading) must not reach the browser, whose JSON.parse rejects it
    state.on_catalog('[{"path": "horizontal", "solutions": {"dp_cp": {"cp_energy_J": NaN}}}]')
    state.on_joint_state(1.0, ["boom_joint"], [math.nan])
    view, _ = state.snapshot()
    assert view["catalog"][0]["solutions"]["dp_cp"]["cp_energy_J"] is None and view["joints"] == {"boom_joint": None}
    json.dumps(view, allow_nan=False)


class FakeActions:
    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    async def acknowledge(self) -> tuple[bool, str]:
        self.calls.append(("acknowledge",))
        return True, "acknowledged: boom: external_leakage_a"

    async def request_path(self, path: str, method: str) -> tuple[bool, str]:
        self.calls.append(("request_path", path, method))
        return True, f"requested {path}"


def _serve(token: str, check, **options: Any) -> tuple[FakeActions, list[str], HmiState]:
    state = HmiState()
    state.on_diagnostics(1.0, [_status(1, "external_leakage_a")])
    state.on_catalog(json.dumps([{"path": "horizontal", "solutions": {"dp_cp": {"cp_energy_J": 7e4}}}]))
    actions, log = FakeActions(), []

    async def run() -> None:
        app = create_app(state, actions, token=token, update_period_s=0.05, log=log.append, **options)
        async with TestClient(TestServer(app)) as client:
            await check(client, state)

    asyncio.run(run())
    return actions, log, state


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_without_a_configured_token_the_hmi_is_read_only():
    async def check(client, _state):
        page = await client.get("/")
        assert page.status == 200 and "hmi.js" in await page.text()
        assert "script-src 'self'" in page.headers["Content-Security-Policy"]
        assert "Access-Control-Allow-Origin" not in page.headers
        view = await (await client.get("/api/state")).json()
        assert view["actions_enabled"] is False and view["tiles"][0]["fault"] == "external_leakage_a"
        refused = await client.post("/api/acknowledge", json={}, headers=_bearer("anything"))
        assert refused.status == 403 and "read-only" in (await refused.json())["error"]

    actions, log, state = _serve("", check)
    assert actions.calls == [] and "refused: read-only" in log[0]
    assert state.snapshot()[0]["alarms"][0]["acknowledged_wall"] is None


def test_actions_need_the_token_the_origin_and_valid_input():
    async def check(client, state):
        assert (await client.post("/api/acknowledge", json={})).status == 401
        assert (await client.post("/api/acknowledge", json={}, headers=_bearer("wrong"))).status == 401
        cross = await client.post("/api/acknowledge", json={}, headers={**_bearer(TOKEN), "Origin": "http://evil.example"})
        assert cross.status == 403 and "cross-origin" in (await cross.json())["error"]
        assert (await client.post("/api/acknowledge", data="{}", headers=_bearer(TOKEN))).status == 415
        huge = await client.post("/api/request", data=json.dumps({"path": "x" * 2 * MAX_BODY_BYTES}),
                                 headers={**_bearer(TOKEN), "Content-Type": "application/json"})
        assert huge.status == 413
        for body, needle in (({"path": "../etc", "method": "dp_cp"}, "identifier"),
                             ({"path": "vertical", "method": "dp_cp"}, "not in the trajectory catalog"),
                             ({"path": "horizontal", "method": "dp_ls"}, "not stored for path"),
                             ({"path": "horizontal"}, "method 'None'")):
            answer = await client.post("/api/request", json=body, headers=_bearer(TOKEN))
            assert answer.status == 400 and needle in (await answer.json())["error"], body
        own_origin = f"http://{client.server.host}:{client.server.port}"
        done = await client.post("/api/acknowledge", json={}, headers={**_bearer(TOKEN), "Origin": own_origin})
        assert done.status == 200 and "external_leakage_a" in (await done.json())["detail"]
        served = await client.post("/api/request", json={"path": "horizontal", "method": "dp_cp"}, headers=_bearer(TOKEN))
        assert served.status == 200
        state.on_halt(True)
        halted = await client.post("/api/request", json={"path": "horizontal", "method": "dp_cp"}, headers=_bearer(TOKEN))
        assert halted.status == 409 and "halt" in (await halted.json())["error"]

    actions, log, state = _serve(TOKEN, check)
    assert actions.calls == [("acknowledge",), ("request_path", "horizontal", "dp_cp")]
    assert sum("refused" in line for line in log) == 10 and all("127.0.0.1" in line for line in log)
    assert state.snapshot()[0]["alarms"][0]["acknowledged_wall"] is not None
    assert [a["ok"] for a in state.snapshot()[0]["actions"]][:3] == [False, True, True]  # newest first: the halt refusal


def test_the_websocket_refuses_other_origins_and_streams_snapshot_then_updates():
    names = ["boom/mean_r_pA", "boom/threshold_pA"]

    async def check(client, state):
        state.on_residuals(1.0, names, [0.01, 0.05])
        foreign = await client.get("/ws", headers={"Origin": "http://evil.example", "Connection": "Upgrade", "Upgrade": "websocket",
                                                   "Sec-WebSocket-Version": "13", "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="})
        assert foreign.status == 403
        async with client.ws_connect("/ws") as ws:
            snapshot = await ws.receive_json(timeout=5)
            assert snapshot["type"] == "snapshot" and snapshot["residuals"]["rows"] == [[1.0, 0.01, 0.05]]
            state.on_residuals(2.0, names, [0.02, 0.05])
            update = await ws.receive_json(timeout=5)
            assert update["type"] == "update" and update["residuals"]["rows"] == [[2.0, 0.02, 0.05]]
            update = await ws.receive_json(timeout=5)
            assert update["residuals"]["rows"] == []  # nothing new: nothing resent

    _serve(TOKEN, check)


@pytest.mark.parametrize("path", ["/static/../server.py", "/static/%2e%2e/server.py", "/static/nothing.js"])
def test_only_the_page_assets_are_served(path):
    async def check(client, _state):
        response = await client.get(path)
        assert response.status in (403, 404)

    _serve("", check)


def test_a_rebound_host_name_is_refused_everywhere():
    """DNS rebinding: evil.example resolved to this address; the browser sends Host and Origin evil.example."""
    async def check(client, _state):
        hostile = {"Host": "evil.example", "Origin": "http://evil.example"}
        for path in ("/", "/api/state", "/ws"):
            answer = await client.get(path, headers=hostile)
            assert answer.status == 421 and "evil.example" in (await answer.json())["error"], path
        acted = await client.post("/api/acknowledge", json={}, headers={**hostile, **_bearer(TOKEN)})
        assert acted.status == 421
        assert (await client.get("/api/state", headers={"Host": "localhost:8080"})).status == 200
        assert (await client.get("/api/state", headers={"Host": "hmi.plant.example"})).status == 200  # allowed_hosts
        assert client.app[GUARD_KEY].counts["refused_hosts"] == 4

    actions, _, _ = _serve(TOKEN, check, allowed_hosts=frozenset({"hmi.plant.example"}))
    assert actions.calls == []


def test_refused_requests_cannot_flood_the_page_or_flush_the_operator_log():
    async def check(client, state):
        for _ in range(MAX_ACTIONS):
            assert (await client.post("/api/acknowledge", json={}, headers=_bearer(TOKEN))).status == 200
        before = len(json.dumps(state.snapshot()[0]))
        for k in range(60):
            origin = f"http://evil{k}.example/" + "x" * 7900
            assert (await client.post("/api/acknowledge", json={}, headers={"Origin": origin})).status == 403
        view = state.snapshot()[0]
        assert len(json.dumps(view)) < before + MAX_REFUSALS * (MAX_DETAIL_CHARS + 200)
        assert [a["ok"] for a in view["actions"]] == [True] * MAX_ACTIONS  # every operator entry kept
        assert len(view["refusals"]) == MAX_REFUSALS and all(len(r["detail"]) <= MAX_DETAIL_CHARS for r in view["refusals"])
        for _ in range(30):  # the same refusal again only counts up
            await client.post("/api/acknowledge", json={}, headers={"Origin": "http://evil.example"})
        assert state.snapshot()[0]["refusals"][0]["count"] == 30

    _, log, _ = _serve(TOKEN, check)
    assert max(len(line) for line in log) < 300


def test_token_guesses_are_slowed_from_any_address_and_the_right_token_always_gets_in():
    """Past TOKEN_FAILURES wrong tokens a client's checks wait, one at a time; a guesser rotating its source addresses
    slows every check once GLOBAL_TOKEN_FAILURES have failed; the right token is accepted throughout."""
    async def check(client, _state):
        guard = client.app[GUARD_KEY]
        guard.tarpit_s = 0.05
        for _ in range(TOKEN_FAILURES):
            assert (await client.post("/api/acknowledge", json={}, headers=_bearer("guess"))).status == 401
        began = time.monotonic()
        assert (await client.post("/api/acknowledge", json={}, headers=_bearer(TOKEN))).status == 200  # slowed, never refused
        assert time.monotonic() - began >= guard.tarpit_s and guard.counts["rate_limited"] == 1
        guard.clock = lambda: time.monotonic() + TOKEN_WINDOW_S + 0.1  # the window has passed: at full speed again
        assert guard.wait_s("127.0.0.1") == 0.0
        guard.clock = time.monotonic
        for k in range(GLOBAL_TOKEN_FAILURES):  # as many guesses, each from another address
            guard.failed(f"127.0.{k // 250}.{k % 250 + 1}")
        assert guard.guessed() and guard.wait_s("127.9.9.9") == 0.0
        began = time.monotonic()
        answers = await asyncio.gather(*(client.post("/api/acknowledge", json={}, headers=_bearer("guess")) for _ in range(8)))
        assert all(a.status == 401 for a in answers)
        assert time.monotonic() - began >= 8 * guard.tarpit_s  # one check at a time: the guess rate is bounded
        assert (await client.post("/api/acknowledge", json={}, headers=_bearer(TOKEN))).status == 200

    actions, _, _ = _serve(TOKEN, check)
    assert actions.calls == [("acknowledge",), ("acknowledge",)]


def test_malformed_requests_are_logged_once_per_interval_without_a_traceback():
    import logging

    from hydro_ros.hmi.server import QUIET_LOG_S, QuietBadRequests

    now = [0.0]
    quiet = QuietBadRequests(clock=lambda: now[0])
    records = []
    for k in range(100):
        try:
            raise ValueError("Invalid header value char")
        except ValueError:
            import sys

            record = logging.LogRecord("aiohttp.server", logging.ERROR, __file__, 1, "Error handling request", (), sys.exc_info())
        now[0] = k * QUIET_LOG_S / 50
        if quiet.filter(record):
            records.append(record)
    assert len(records) == 2 and all(r.exc_info is None for r in records)
    assert "ValueError" in records[0].getMessage() and "49 more" in records[1].getMessage()


def test_the_alarm_log_is_served_paged_and_read_only(tmp_path):
    from hydro_ros.fdi.alarm_log import AlarmLog

    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    for k in range(30):
        log.record("raised" if k % 2 == 0 else "cleared", "boom", f"fault_{k}", 1)

    async def check(client, _state):
        page = await (await client.get("/api/alarm_log?offset=20&limit=20")).json()
        assert page["total"] == 30 and [e["fault"] for e in page["events"]] == [f"fault_{k}" for k in range(9, -1, -1)]
        for query in ("limit=1000", "offset=-1", "offset=x"):
            assert (await client.get(f"/api/alarm_log?{query}")).status == 400, query
        assert (await client.post("/api/alarm_log")).status == 405

    _serve(TOKEN, check, alarm_log=path)
    assert len(log._db.execute("SELECT id FROM alarm_events").fetchall()) == 30

    async def without(client, _state):
        answer = await client.get("/api/alarm_log")
        assert answer.status == 404 and "no alarm log" in (await answer.json())["error"]

    _serve(TOKEN, without)


def test_the_page_tells_a_pause_from_a_stop():
    """/fdi/halt is true for a hold (the monitor cannot vouch) and for a severe fault; the monitor's hydro_ros/fdi_halt status
    says which, and the page's state carries it (hmi.js: PAUSED against HALT REQUESTED)."""
    state = HmiState(plot_window_s=10.0, plot_period_s=0.1, stale_timeout_s=3.0)
    state.on_halt(True)
    state.on_diagnostics(1.0, [StatusReport("hydro_ros/fdi_halt", 1, "paused: monitor not vouching (boom: inputs stale)", "sam",
                                            {"halt": "true", "kind": "hold"})])
    view = state.snapshot()[0]
    assert view["halt"] is True and view["halt_kind"] == "hold" and "inputs stale" in view["halt_reason"]
    state.on_diagnostics(2.0, [StatusReport("hydro_ros/fdi_halt", 2, "stop: severe fault (boom: spool_stuck_closed)", "sam",
                                            {"halt": "true", "kind": "fault"})])
    assert state.snapshot()[0]["halt_kind"] == "fault" and not state.snapshot()[0]["tiles"]
