"""fdi_node's alarm log without ROS: what latches across a restart, paging, and a log that never stops the monitor
nor loses an event: a full disk, a file that cannot be opened, deleted or corrupt."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hydro_ros.fdi.alarm_log import AlarmLog, read_events


def test_latched_alarms_survive_a_restart_and_an_acknowledgement_until_a_reset(tmp_path):
    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    log.record("raised", "boom", "unisolated", 1, stamp_s=12.5, evidence={"pattern": "0100"})
    log.record("changed", "boom", "external_leakage_a", 1, stamp_s=12.5)
    log.record("raised", "stick", "spool_stuck_closed", 2)
    AlarmLog(path, "other_machine").record("raised", "boom", "internal_leakage", 1)
    log.close()  # the process dies here

    again = AlarmLog(path, "sam")
    latched = {alarm.actuator: (alarm.fault, alarm.level, alarm.stamp_s) for alarm in again.latched()}
    assert latched == {"boom": ("external_leakage_a", 1, 12.5), "stick": ("spool_stuck_closed", 2, None)}
    again.record("acknowledged", "", evidence={"detail": "operator"})  # silenced, not cleared
    assert {alarm.actuator for alarm in again.latched()} == {"boom", "stick"}
    again.record("cleared", "boom", "external_leakage_a")
    assert [alarm.actuator for alarm in again.latched()] == ["stick"]
    again.record("reset", "", evidence={"detail": "maintenance"})
    assert again.latched() == []
    again.record("raised", "boom", "internal_leakage", 1)
    again.record("cleared", "boom", "internal_leakage")
    assert again.latched() == []
    with pytest.raises(ValueError):
        again.record("exploded", "boom")


def test_events_are_paged_newest_first_and_exported(tmp_path):
    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    for k in range(25):
        log.record("raised" if k % 2 == 0 else "cleared", "boom", f"fault_{k}", 1, evidence={"k": k})
    page, total = read_events(path, offset=10, limit=10)
    assert total == 25 and [event["evidence"]["k"] for event in page] == list(range(14, 4, -1))
    out_csv, out_json = tmp_path / "alarms.csv", tmp_path / "alarms.json"
    done = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "alarms", "export", "--db", str(path), "--out", str(out_csv),
                           "--out", str(out_json)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    exported = json.loads(out_json.read_text())
    assert [event["fault"] for event in exported] == [f"fault_{k}" for k in range(25)]
    assert out_csv.read_text().splitlines()[0].startswith("id,wall_time,stamp_s,machine,actuator,event")
    missing = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "alarms", "export", "--db", str(tmp_path / "none"),
                              "--out", str(out_json)], capture_output=True, text=True, timeout=120)
    assert missing.returncode == 1 and missing.stderr.count("\n") == 1 and "no such file" in missing.stderr


def _faults(path) -> list[str]:
    return [event["fault"] for event in read_events(path, newest_first=False)[0]]


def test_a_full_disk_keeps_the_events_in_memory_and_writes_them_when_space_returns(tmp_path):
    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    pages = log._db.execute("PRAGMA page_count").fetchone()[0]
    log._db.execute(f"PRAGMA max_page_count = {pages}")  # the disk is full from here on
    results = [log.record("raised", "boom", f"fault_{k}", 1, evidence={"pad": "x" * 2000}) for k in range(20)]
    assert not all(results) and log.failed_writes >= 1 and "full" in log.error and log.pending
    log._db.execute("PRAGMA max_page_count = 1073741823")  # space again
    assert log.flush() and log.error == "" and not log.pending
    assert _faults(path) == [f"fault_{k}" for k in range(20)]  # none lost, in order


def test_a_log_that_cannot_be_opened_is_an_error_and_opens_once_it_can(tmp_path):
    blocker = tmp_path / "var"
    blocker.write_text("a file where the log's directory should be")
    path = blocker / "alarms.sqlite"
    log = AlarmLog(path, "sam")  # never raises: the monitor must start
    assert "cannot open" in log.error and log.latched() == []
    assert not log.record("raised", "boom", "external_leakage_a", 1) and len(log.pending) == 1
    blocker.unlink()
    assert log.record("changed", "boom", "internal_leakage", 1) and log.error == ""
    assert _faults(path) == ["external_leakage_a", "internal_leakage"]


def test_a_deleted_log_is_noticed_and_a_new_one_started(tmp_path):
    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    log.record("raised", "boom", "external_leakage_a", 1)
    for suffix in ("", "-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    assert log.record("changed", "boom", "internal_leakage", 1)
    assert log.reopened == 1 and _faults(path) == ["internal_leakage"]


def test_a_corrupt_log_is_moved_aside_and_a_new_one_started(tmp_path):
    path = tmp_path / "alarms.sqlite"
    path.write_bytes(b"this is not a database" * 100)
    log = AlarmLog(path, "sam")
    assert log.error == "" and len(log.moved_aside) == 1 and log.moved_aside[0].read_bytes().startswith(b"this is not")
    assert log.record("raised", "boom", "external_leakage_a", 1) and _faults(path) == ["external_leakage_a"]
