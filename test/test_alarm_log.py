"""fdi_node's alarm log without ROS: what latches across a restart, paging, and a full disk."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.alarm_log import AlarmLog, read_events


def test_latched_alarms_survive_a_restart_until_acknowledged(tmp_path):
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
    again.record("acknowledged", "", evidence={"detail": "operator"})
    again.record("cleared", "boom", "external_leakage_a")
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
    done = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "alarms", "export", "--db", str(path), "--csv", str(out_csv),
                           "--json", str(out_json)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    exported = json.loads(out_json.read_text())
    assert [event["fault"] for event in exported] == [f"fault_{k}" for k in range(25)]
    assert out_csv.read_text().splitlines()[0].startswith("id,wall_time,stamp_s,machine,actuator,event")
    missing = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "alarms", "export", "--db", str(tmp_path / "none"),
                              "--json", str(out_json)], capture_output=True, text=True, timeout=120)
    assert missing.returncode == 1 and missing.stderr.count("\n") == 1 and "no such file" in missing.stderr


def test_a_full_disk_is_a_status_not_a_crash(tmp_path):
    path = tmp_path / "alarms.sqlite"
    log = AlarmLog(path, "sam")
    pages = log._db.execute("PRAGMA page_count").fetchone()[0]
    log._db.execute(f"PRAGMA max_page_count = {pages}")  # the disk is full from here on
    results = [log.record("raised", "boom", "external_leakage_a", 1, evidence={"pad": "x" * 2000}) for _ in range(20)]
    assert not all(results) and log.failed_writes >= 1 and "full" in log.error
    log._db.execute("PRAGMA max_page_count = 1073741823")  # space again
    assert log.record("cleared", "boom", "external_leakage_a") and log.error == ""


def test_an_unopenable_log_is_one_line(tmp_path):
    (tmp_path / "dir.sqlite").mkdir()
    with pytest.raises(InputError, match="cannot open"):
        AlarmLog(tmp_path / "dir.sqlite", "sam")
