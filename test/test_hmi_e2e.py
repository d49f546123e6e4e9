"""The HMI end to end in headless Chromium: plant_sim -> fdi_node -> hmi -> the page an operator sees.

A leak injected into the running plant turns the boom's tile WARN with the fault's name; the
acknowledge button is refused without the operator token and clears the latch with it; a catalog
entry's Request button reaches the trajectory server's request topic. The screenshot in docs/hmi.md
is the one this test writes (out/hmi.png).
"""

from __future__ import annotations

import json
import shutil

from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from hydro_ros.contract import topics
from hydro_ros.nodes.common import LATCHED_QOS
from hydro_ros.nodes.hmi import TOKEN_ENV
from test.browser import chromium_page
from test.conftest import REPO, SAM_CONFIG
from test.ros_graph import free_port, node_output, node_process, port_open, probe_node, spinning, wait_for

TOKEN = "hmi-e2e-token"
SCREENSHOT = REPO / "out" / "hmi.png"
TILE = "[data-actuator=boom]"


def _tile_is(page, level: str, fault: str | None = None, timeout_s: float = 30.0) -> None:
    page.wait_for_function(
        """([selector, level, fault]) => {
             const tile = document.querySelector(selector);
             return tile && tile.dataset.level === level && (fault === null || tile.querySelector('.fault').textContent === fault);
           }""", arg=[TILE, level, fault], timeout=timeout_s * 1000)


def _set_fault(client: AsyncParameterClient, name: str, value: float) -> None:
    future = client.set_parameters([Parameter(f"fault.{name}", value=value)])
    assert wait_for(future.done, 10), f"plant_sim did not take fault.{name}"
    assert future.result().results[0].successful


def _click_and_read_status(page, selector: str) -> str:
    page.evaluate("() => { document.getElementById('action-status').textContent = ''; }")
    page.click(selector)
    page.wait_for_function("() => /^(done|refused)/.test(document.getElementById('action-status').textContent)", timeout=10_000)
    return page.text_content("#action-status")


def test_operator_sees_the_leak_and_acknowledges_it_only_with_the_token(ros_domain, chromium, monkeypatch, tmp_path):
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    port = free_port()
    requests: list[str] = []
    residuals: list[JointState] = []
    catalog = [{"machine": "k70m", "path": "horizontal", "description": "", "duration_s": 20.0,
                "solutions": {"dp_cp": {"cp_energy_J": 69.9e3, "ls_energy_J": 51.0e3, "limits_ok": True},
                              "pinv_joint": {"cp_energy_J": 82.5e3, "ls_energy_J": 60.2e3, "limits_ok": True}}}]
    # the plant at half real time: plant_sim, fdi_node, hmi and a browser at 1 kHz overload this 2-core machine
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}", "-p", "seed:=3", "-p", "real_time_factor:=1.0"), \
            node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={SAM_CONFIG}", "-p", f"alarm_log:={tmp_path / 'alarms.sqlite'}"), \
            node_process("hydro_ros.nodes.hmi", "-p", f"port:={port}", "-p", f"alarm_log:={tmp_path / 'alarms.sqlite'}",
                         "-p", "foxglove_port:=-1") as hmi, \
            probe_node("trajectory_server_stand_in") as node, spinning(node), chromium_page() as page:
        # a stand-in for trajectory_server: the latched catalog, and an answer to every request
        node.create_publisher(String, "/trajectory_server/catalog", LATCHED_QOS).publish(String(data=json.dumps(catalog)))
        results = node.create_publisher(String, "/trajectory_server/result", LATCHED_QOS)

        def answer(msg: String) -> None:
            requests.append(msg.data)
            request = json.loads(msg.data)
            results.publish(String(data=json.dumps({"path": request["path"], "method": request["method"], "ok": True, "error": ""})))

        node.create_subscription(String, "/trajectory_server/request", answer, 10)
        node.create_subscription(JointState, topics.FDI_RESIDUALS, residuals.append, 10)
        plant = AsyncParameterClient(node, "plant_sim")
        assert plant.wait_for_services(15.0)
        # on a loaded machine the hmi process can take longer to listen than plant_sim to offer its services
        assert wait_for(lambda: port_open(port), 30), f"hmi did not listen on {port}: {hmi.poll()}"

        page.goto(f"http://127.0.0.1:{port}/")
        _tile_is(page, "OK", "ok", timeout_s=60)
        page.wait_for_selector("#plots canvas", timeout=10_000)
        # the tile and the halt come on two topics: the page says "no halt request" once /fdi/halt confirms
        page.wait_for_function("() => document.getElementById('halt').textContent === 'no halt request'", timeout=10_000)
        page.wait_for_function("() => /^boom_joint -?[0-9.]+ rad$/.test(document.getElementById('joints').textContent)", timeout=10_000)
        page.wait_for_timeout(5_000)  # the residual window is full on the healthy plant
        _set_fault(plant, "external_leakage_a", 3.0)
        _tile_is(page, "WARN", "external_leakage_a", timeout_s=60)
        assert "external_leakage_a" in page.text_content("#alarms tbody tr")
        assert page.text_content("#halt") == "no halt request"  # a leak is minor: a warning, no halt

        page.fill("#token", TOKEN)
        assert _click_and_read_status(page, "button.request[data-path=horizontal][data-method=dp_cp]").startswith("done")
        assert wait_for(lambda: requests == [json.dumps({"path": "horizontal", "method": "dp_cp"})], 10), requests
        page.wait_for_function("() => document.getElementById('result').textContent.startsWith('served horizontal')",
                               timeout=10_000)
        page.wait_for_timeout(1_000)  # one more residual update on the plots
        SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(tmp_path / "hmi.png"), full_page=True)
        shutil.copyfile(tmp_path / "hmi.png", SCREENSHOT)

        # the leak repaired, the alarm stays latched until the operator acknowledges it
        _set_fault(plant, "external_leakage_a", 0.0)
        assert wait_for(lambda: residuals and all(abs(residuals[-1].position[k]) < residuals[-1].position[k + 1] for k in (0, 2)), 60), \
            "residuals did not return inside their thresholds after the repair"
        page.fill("#token", "")
        assert _click_and_read_status(page, "#acknowledge") == "refused: operator token required"
        page.fill("#token", "not-the-token")
        assert _click_and_read_status(page, "#acknowledge") == "refused: operator token rejected"
        page.wait_for_timeout(1_500)
        _tile_is(page, "WARN", "external_leakage_a", timeout_s=1)  # refused: still latched
        page.fill("#token", TOKEN)
        assert _click_and_read_status(page, "#acknowledge").startswith("done: acknowledged: boom: external_leakage_a")
        # an acknowledgement silences the alarm, never clears it: the latched fault stays shown until a reset
        page.wait_for_timeout(2_000)
        _tile_is(page, "WARN", "external_leakage_a", timeout_s=1)
        reset = node.create_client(Trigger, "/fdi_node/reset")  # maintenance's reset (its SROS2 enclave on a machine)
        assert reset.wait_for_service(timeout_sec=10)
        answer = reset.call_async(Trigger.Request())
        assert wait_for(answer.done, 10) and answer.result().success, answer.result()
        _tile_is(page, "OK", "ok", timeout_s=60)  # once the re-armed monitor has looked again and found the leak gone
        alarm = page.text_content("#alarms tbody tr")
        assert "cleared" in alarm and "acknowledged" in alarm
        # the alarm log, newest first: the acknowledgement, and below it the alarm as raised
        page.wait_for_function("() => document.querySelector('#alarm-log tbody tr[data-event=acknowledged]') !== null", timeout=15_000)
        logged = page.text_content("#alarm-log tbody")
        assert "external_leakage_a" in logged and ("raised" in logged or "changed" in logged)
        refused = page.text_content("#refusals")  # the two attempts without a valid token, apart from the actions
        assert "operator token required" in refused and "operator token rejected" in refused
        latencies = page.evaluate("() => window.hmiLatencies")
        assert latencies and all(0.0 <= s < 5.0 for s in latencies), latencies  # /diagnostics stamp -> DOM
    log = node_output(hmi)
    assert "operator action acknowledge from 127.0.0.1 refused: operator token required" in log
    assert "operator action acknowledge from 127.0.0.1: done" in log and "request_path horizontal dp_cp" in log
