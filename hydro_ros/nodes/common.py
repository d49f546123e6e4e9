"""QoS profiles named once, and the one `main` shape every executable shares (ros2/examples)."""

from __future__ import annotations

import importlib
import math
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.nodes.parameters import Spec
from hydro_ros.safety.motion import HEARTBEAT_TIMEOUT_S, VALVE_COMMAND_TIMEOUT_S

SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=topics.SENSOR_QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
# State that late joiners must see (halt, catalog, results).
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
# the newest sample only, for a subscription that is never spun but taken from by a timer (rclpy's wait_for_message habit)
LATEST_ONLY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
# operator services: rclpy's default keeps 10 requests, and the rest of a burst was lost unanswered
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
# /fdi/halt: latched, re-published every HEARTBEAT_PERIOD_S with an offered deadline of the heartbeat timeout, so a
# consumer that asks for a deadline can tell a live monitor from a dead one; what a sample authorises is decided by its
# source stamp (hydro_ros.safety.motion), never by its arrival: a latched sample replayed to a late joiner is old
HALT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
    deadline=Duration(seconds=HEARTBEAT_TIMEOUT_S),
)


# the two nodes that put sensor samples on the graph (plant_sim, can_bridge) offer the same outputs: a crane at 1 kHz is
# ~19 000 per-sample messages a second, more than rclpy carries, so its monitor takes sample blocks instead
SENSOR_TOPICS = Spec("all", "which of the contract's per-sample sensor topics to publish: all, only /joint_states (what a "
                            "trajectory server and an HMI read, when the monitor takes sample blocks), none",
                     choices=("all", "joint_states", "none"))
SAMPLE_BLOCKS = Spec(False, f"also publish every tick's samples as one message on {topics.SAMPLE_BLOCK} (fdi_node input:=sample_block)")


# every consumer of /hydraulics/valve_commands (can_bridge forwarding, plant_sim, crane_sim) goes neutral when its
# freshest command is older than this (hydro_ros.safety.motion.ValveDeadman): a controller that died cannot leave a valve open
VALVE_COMMAND_TIMEOUT = Spec(VALVE_COMMAND_TIMEOUT_S, "[s wall] a valve whose last command is older than this is commanded "
                                                      "neutral (deadman)", 0.01, 5.0)


# the hardware_id of every status a node publishes: the machine instance, so two machines of one type stay apart
MACHINE_ID = Spec("", "this machine instance's hardware_id on /diagnostics; empty: the node's namespace (m1), else the "
                      "machine's name from its config")


def machine_instance(node: Node, machine_name: str) -> str:
    """The hardware_id of ``node``'s statuses: its ``machine_id`` parameter, else its namespace, else the machine's name."""
    return node.params.machine_id or node.get_namespace().strip("/") or machine_name


def checked_valve_commands(names: list[str], positions: list[float], actuators: list[str]) -> tuple[dict[str, float], dict[str, str]]:
    """The valve commands of a /hydraulics/valve_commands message for ``actuators``: (accepted, refused with the reason).

    A command is a normalised opening in [-1, 1]; a non-finite or out-of-range one is refused (never clamped to a full
    opening), and so is every command of a message whose names and positions differ in length or that names a valve
    twice. The caller commands a refused valve neutral.
    """
    ours = [name for name in names if name in actuators]
    if len(names) != len(positions):
        return {}, {name: f"{len(names)} names but {len(positions)} positions" for name in ours}
    if len(set(names)) != len(names):
        return {}, {name: "a valve named twice in the message" for name in ours}
    accepted, refused = {}, {}
    for name, value in zip(names, positions):
        if name in actuators:
            if math.isfinite(value) and -1.0 <= value <= 1.0:
                accepted[name] = float(value)
            else:
                refused[name] = f"{value!r} outside [-1, 1]"
    return accepted, refused


def without_node_name(argv: list[str]) -> list[str]:
    """The ``--ros-args`` of a process's command line without its node-name remaps (``__node``/``__name``), as the
    arguments of a second node of the process: launch's ``name`` (``-r __node:=hmi``) would otherwise name both, while
    its namespace and topic remaps must apply to both."""
    out, inside, skip = [], False, False
    for k, arg in enumerate(argv):
        if skip:
            skip = False
            continue
        if arg == "--ros-args":
            inside = True
            continue
        if arg == "--":
            inside = False
            continue
        if not inside:
            continue
        if arg in ("-r", "--remap") and k + 1 < len(argv):
            skip = True
            if argv[k + 1].split(":=")[0].split(":")[-1] in ("__node", "__name"):  # also a node's own "hmi:__node:=..."
                continue
            out += [arg, argv[k + 1]]
            continue
        out.append(arg)
    return ["--ros-args", *out] if out else []


def publishes_sensor_topic(chosen: str, topic: str) -> bool:
    """Whether the sensor_topics choice ``chosen`` includes ``topic``."""
    return chosen == "all" or (chosen == "joint_states" and topic == topics.JOINT_STATES)


def relative(topic: str) -> str:
    """A contract topic as a name the node's namespace applies to (/joint_states -> joint_states). /diagnostics stays
    absolute, as diagnostic_updater keeps it: the aggregator, rqt_robot_monitor and Foxglove read it in the root
    namespace, and :func:`namespaced_statuses` keeps the machines on it apart."""
    return topic if topic == topics.DIAGNOSTICS else topic.lstrip("/")


def namespaced_statuses(node: Node, statuses: list) -> list:
    """``statuses`` named for the graph: in a namespace, ``machine1/hydro_ros/fdi/boom`` (two machines share one
    /diagnostics); in the root namespace as they are."""
    prefix = node.get_namespace().strip("/")
    if prefix:
        for status in statuses:
            status.name = f"{prefix}/{status.name}"
    return statuses


def own_statuses(node: Node, statuses: list) -> list:
    """The statuses on /diagnostics of the machine in ``node``'s namespace, their names as in the root namespace."""
    prefix = node.get_namespace().strip("/")
    if not prefix:
        return [s for s in statuses if s.name.startswith("hydro_ros/")]
    return [s for s in statuses if s.name.startswith(f"{prefix}/hydro_ros/")]


def message_class(type_name: str) -> Any:
    """'sensor_msgs/msg/FluidPressure' -> the Python class."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> None:
    """Init, spin, shut down cleanly: SIGINT and SIGTERM end the spin without a traceback.

    Every node handles the two signals itself: rclpy's own handlers shut the context down first, after which a timer
    still due publishes into an invalid context (a traceback) and nothing can be sent (a valve's neutral command). Here
    the signal ends the spin (see `stop_signals`), and the node is destroyed while its publishers still work.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node, executor = None, None
    with stop_signals() as stop:
        try:
            try:
                node = factory()
            except InputError as exc:  # bad parameter or config (ConfigError is one): one line, no traceback
                print(f"{getattr(factory, '__name__', 'node')}: error: {exc}", file=sys.stderr)
                raise SystemExit(2) from None
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        except ExternalShutdownException:
            pass
        finally:
            if node is not None:
                node.destroy_node()
            if executor is not None:
                executor.shutdown()
            if rclpy.ok():
                rclpy.shutdown()


SPIN_PERIOD_S = 0.1  # the longest a stop request waits for an idle executor's wait set to return


@contextmanager
def stop_signals() -> Iterator[threading.Event]:
    """SIGINT and SIGTERM set the event yielded, for a spin loop to look at between callbacks; the handlers before come
    back on exit. The handler raises nothing: an exception raised wherever a signal happens to land (inside rclpy's Task
    constructor, in a binding's argument conversion, halfway through a bag write) left half-built objects whose
    finalisers printed tracebacks at exit; a second signal cannot cut a node's last words short either."""
    stop = threading.Event()
    previous = {number: signal.signal(number, lambda *_: stop.set()) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def destroy_entities(node: Any, entities: list[Any]) -> None:
    """Destroy what a lifecycle node created in configure: timers, subscriptions, lifecycle publishers."""
    for entity in entities:
        if isinstance(entity, Timer):
            node.destroy_timer(entity)
        elif isinstance(entity, Subscription):
            node.destroy_subscription(entity)
        else:
            node.destroy_lifecycle_publisher(entity)
    entities.clear()
