"""The safety core: pure state machines (no rclpy) that decide what may move the machine.

- :mod:`hydro_ros.safety.supervisor`: the monitor's vouching, alarm latching and the ``/fdi/halt`` output;
- :mod:`hydro_ros.safety.motion`: the executor's authority to move and the valve deadman of every command consumer.

The nodes are adapters (messages in, decisions out); the invariants are stated in each module and in
docs/monitoring.md ("The safety core"), and tested on random event sequences (test/test_safety_core.py).
"""
