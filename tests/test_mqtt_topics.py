"""The MQTT bridge's pure parts (no broker, no paho): topics, decimation, the bounded
buffer, payloads, Home Assistant discovery."""
import json
from datetime import datetime, timezone

from imucald.mqtt.topics import (Decimator, OutBuffer, Topics, cal_payload, calibration_summary,
                                 discovery_messages, health_payload, sample_payload)


def test_topics_carry_the_sensor_id():
    t = Topics("site/lab/", "0123456789ab")
    assert (t.status, t.imu, t.health, t.calibration, t.event("cal")) == (
        "site/lab/0123456789ab/status", "site/lab/0123456789ab/imu", "site/lab/0123456789ab/health",
        "site/lab/0123456789ab/calibration", "site/lab/0123456789ab/event/cal")


def test_decimator_takes_the_first_sample_of_each_interval_on_the_stream_clock():
    d = Decimator(20.0)
    seq = [i for i in range(1000) if d.accept(i / 100.0)]          # 100 Hz -> 20 Hz
    assert seq == list(range(0, 1000, 5))
    d = Decimator(20.0)
    late = [i for i in range(3, 40) if d.accept(i / 100.0)]        # joined mid-interval
    assert late == [3, 5, 10, 15, 20, 25, 30, 35]
    assert d.accept(0.0)                                           # the daemon restarted: t back to 0
    d = Decimator(1000.0)
    assert all(d.accept(i / 1000.0) for i in range(5000))          # at the stream's rate: every one


def test_out_buffer_drops_the_oldest_and_counts_per_kind():
    b = OutBuffer(3)
    for i in range(5):
        b.put((f"p/id/{'imu' if i != 1 else 'health'}", str(i).encode(), 1, False))
    assert [m[1] for m in b.q] == [b"2", b"3", b"4"]
    assert b.dropped == 2 and b.dropped_by == {"imu": 1, "health": 1}
    m = b.get()
    b.put((m[0], b"5", 1, False))
    b.put_front(m)                                                  # full: the returned one is dropped
    assert b.dropped == 3 and [x[1] for x in b.q] == [b"3", b"4", b"5"]


def test_payloads():
    rec = {"class": "IMU", "seq": 7, "t": 0.07, "acc_g": [0, 0, 1], "still": True, "cal": 2}
    p = sample_payload(rec, 1000.5)
    assert "class" not in p and p["seq"] == 7 and p["time"] == 1000.5
    cal = {"class": "CALIBRATION", "id": 3, "created": "2026-01-01T12:00:00+00:00", "board": "mpu6050",
           "provisional": None, "accel": {"model": "triangular9", "method": "ga",
                                          "params": {"bias_g": [0.01, 0, 0]},
                                          "stderr": {"bias_g": [1e-4, 2e-4, None]},
                                          "quality": {"heldout_rms_g": 0.001}}}
    s = calibration_summary(cal)
    assert s["provisional"] is False and s["accel"]["stderr"]["bias_g"][2] is None
    ev = cal_payload({"class": "CAL", "id": 3, "applied": True, "accel_heldout_rms_g": 0.001}, cal, 5.0)
    assert ev["accel"]["stderr"]["bias_g"][0] == 1e-4 and ev["accel_heldout_rms_g"] == 0.001
    # a calibration that is not the event's (already replaced) is not attached
    assert "accel" not in cal_payload({"class": "CAL", "id": 2, "applied": True}, cal, 5.0)
    now = datetime(2026, 1, 1, 13, 0, tzinfo=timezone.utc).timestamp()
    st = {"rate_hz": 100.0, "calibration_id": 3, "calibration_created": "2026-01-01T12:00:00+00:00",
          "board_stats": {"samples": 10, "gaps": 2, "missing": 9, "bus_faults": 1},
          "bus_stats": {"errors": {"121": 2, "5": 1}}, "state": {"ok": False}}
    h = health_payload(st, 99.5, {"dropped": 0}, now)
    assert h["calibration_age_s"] == 3600.0 and h["gaps"] == 2 and h["missing_samples"] == 9
    assert h["faults"]["bus_errors"] == 3 and h["faults"]["state_ok"] is False
    assert health_payload({**st, "calibration_id": 0}, None, {}, now)["calibration_age_s"] is None
    json.dumps(h, allow_nan=False)


def test_discovery_groups_one_device_per_sensor():
    t = Topics("imucald", "0123456789ab")
    msgs = discovery_messages("homeassistant", t, {"sensor_id": "0123456789ab", "board": "mpu6050",
                                                   "chips": {"accel": "mpu6050"}, "release": "0.1.0"})
    confs = [json.loads(p) for _, p in msgs]
    assert all(topic.startswith("homeassistant/sensor/imucald_0123456789ab/") and topic.endswith("/config")
               for topic, _ in msgs)
    assert len({c["unique_id"] for c in confs}) == len(confs)
    assert {c["device"]["identifiers"][0] for c in confs} == {"imucald_0123456789ab"}
    age = [c for c in confs if c["unique_id"].endswith("_cal_age")][0]
    assert age["state_topic"] == t.health and age["unit_of_measurement"] == "s"
    assert all(c["availability_topic"] == t.status for c in confs)
