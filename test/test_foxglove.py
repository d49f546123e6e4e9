"""Foxglove live: a client speaking the Foxglove WebSocket protocol receives the graph through the hmi node."""

from __future__ import annotations

import asyncio
import json
import struct

import aiohttp
import pytest

from hydro_ros.bags.writer import TYPESTORE
from hydro_ros.contract import topics
from test.conftest import SAM_CONFIG
from test.ros_graph import free_port, node_process

pytest.importorskip("foxglove", reason="foxglove-sdk is an optional extra")


async def _watch(port: int, wanted: tuple[str, ...], seconds: float) -> tuple[dict, dict, dict[str, list[bytes]], list[dict]]:
    """serverInfo, the advertised channels, the payloads received per wanted topic, and the status messages."""
    received: dict[str, list[bytes]] = {topic: [] for topic in wanted}
    statuses: list[dict] = []
    channels: dict[str, dict] = {}
    info: dict = {}
    async with aiohttp.ClientSession() as session:
        for _ in range(100):  # the node may still be starting
            try:
                ws = await session.ws_connect(f"http://127.0.0.1:{port}/", protocols=["foxglove.sdk.v1"])
                break
            except aiohttp.ClientError:
                await asyncio.sleep(0.2)
        by_subscription: dict[int, str] = {}
        end = asyncio.get_running_loop().time() + seconds
        # /diagnostics carries plant_sim's and the hmi's statuses too: enough of it to hold fdi_node's
        while asyncio.get_running_loop().time() < end and not all(len(v) >= (8 if t == topics.DIAGNOSTICS else 3)
                                                                  for t, v in received.items()):
            try:
                message = await asyncio.wait_for(ws.receive(), 1.0)
            except TimeoutError:
                continue
            if message.type == aiohttp.WSMsgType.TEXT:
                data = json.loads(message.data)
                if data["op"] == "serverInfo":
                    info = data
                    # a client that tries to publish is told it cannot
                    await ws.send_str(json.dumps({"op": "advertise", "channels": [
                        {"id": 1, "topic": "/hydraulics/valve_commands", "encoding": "cdr", "schemaName": topics.JOINT_STATE_TYPE}]}))
                elif data["op"] == "advertise":
                    new = [c for c in data["channels"] if c["topic"] in wanted and c["topic"] not in channels]
                    for channel in new:
                        channels[channel["topic"]] = channel
                        by_subscription[len(by_subscription) + 1] = channel["topic"]
                    if new:
                        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": sid, "channelId": channels[topic]["id"]} for sid, topic in by_subscription.items()
                            if topic in {c["topic"] for c in new}]}))
                elif data["op"] == "status":
                    statuses.append(data)
            elif message.type == aiohttp.WSMsgType.BINARY and message.data[0] == 0x01:
                (subscription,) = struct.unpack_from("<I", message.data, 1)
                received[by_subscription[subscription]].append(message.data[13:])
            elif message.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                break
        await ws.close()
    return info, channels, received, statuses


async def _hostile(port: int) -> dict[str, int]:
    """The status each hostile connection attempt gets from the Foxglove gate."""
    from hydro_ros.hmi.server import MAX_FOXGLOVE_CLIENTS

    url = f"http://127.0.0.1:{port}/"
    out = {}
    async with aiohttp.ClientSession() as session:
        for case, headers in (("origin", {"Origin": "http://evil.example"}), ("host", {"Host": "evil.example"})):
            try:
                async with session.ws_connect(url, protocols=["foxglove.sdk.v1"], headers=headers):
                    out[case] = 101
            except aiohttp.WSServerHandshakeError as exc:
                out[case] = exc.status
        admitted = [await session.ws_connect(url, protocols=["foxglove.sdk.v1"]) for _ in range(MAX_FOXGLOVE_CLIENTS)]
        try:
            async with session.ws_connect(url, protocols=["foxglove.sdk.v1"]):
                out["over_cap"] = 101
        except aiohttp.WSServerHandshakeError as exc:
            out["over_cap"] = exc.status
        for ws in admitted:
            await ws.close()
    return out


def test_a_foxglove_client_receives_diagnostics_and_residuals_and_cannot_publish(ros_domain):
    port = free_port()
    wanted = (topics.DIAGNOSTICS, topics.FDI_RESIDUALS, topics.pressure_a("boom"))
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}", "-p", "real_time_factor:=1.0"), \
            node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={SAM_CONFIG}"), \
            node_process("hydro_ros.nodes.hmi", "-p", f"config:={SAM_CONFIG}", "-p", "port:=0", "-p", f"foxglove_port:={port}"):
        info, channels, received, statuses = asyncio.run(_watch(port, wanted, 60.0))
        refused = asyncio.run(_hostile(port))
    # a page from another site in the operator's browser, a rebound DNS name, a flood of connections: refused
    assert refused == {"origin": 403, "host": 421, "over_cap": 503}, refused
    assert info["capabilities"] == []  # read-only: no client publish, no services, no parameters
    assert any("clientPublish" in status["message"] for status in statuses)
    for topic in wanted:
        assert channels[topic]["encoding"] == "cdr" and channels[topic]["schemaEncoding"] == "ros2msg"
        assert len(received[topic]) >= 3, topic
    residuals = TYPESTORE.deserialize_cdr(received[topics.FDI_RESIDUALS][-1], topics.JOINT_STATE_TYPE)
    assert list(residuals.name) == topics.fdi_residual_channels(["boom"])
    diagnostics = [TYPESTORE.deserialize_cdr(payload, "diagnostic_msgs/msg/DiagnosticArray") for payload in received[topics.DIAGNOSTICS]]
    assert any(status.name == f"{topics.FDI_STATUS_PREFIX}boom" for array in diagnostics for status in array.status)
    pressure = TYPESTORE.deserialize_cdr(received[topics.pressure_a("boom")][-1], topics.FLUID_PRESSURE_TYPE)
    assert 1e5 < pressure.fluid_pressure < 3e7
