"""The MQTT bridge's retained calibration under two threads fetching it (imucald/mqtt/bridge.py
_publish_calibration): no broker needed, the control socket replaced by a function."""
import json
import threading

import pytest

pytest.importorskip("paho.mqtt")

from imucald.daemon.config import validate  # noqa: E402
from imucald.mqtt.bridge import Bridge  # noqa: E402
from imucald.mqtt.topics import Decimator, Topics  # noqa: E402


def _cal(i):
    return {"class": "CALIBRATION", "id": i, "created": "2026-01-01T00:00:00+00:00",
            "accel": {"model": "triangular9", "params": {}, "stderr": {"bias_g": [1e-5 * i] * 3}}}


def test_an_older_calibration_fetched_first_is_not_left_retained(tmp_path):
    """The main loop's status poll sees calibration #5 as new and fetches it; before it
    publishes, the daemon applies #6 and the reader thread, on its CAL event, fetches and
    publishes #6.  The retained calibration topic must end at #6 (and the bridge's cal_id
    at 6, the CAL event enriched with #6's standard errors).  Seen to fail with the two
    fetches unlocked, as they were: #5 published after #6 stayed retained, cal_id 5."""
    b = Bridge(validate({}), runtime_dir=str(tmp_path))
    topics = Topics("imucald", "sensor1")
    b.cal_id = 4                                # as _session leaves it: #4 published before
    reader_put_6 = threading.Event()
    in_force = {"id": 5}
    sent = []
    put = b.put

    def recording_put(topic, payload, retain=False):
        sent.append((topic, json.loads(payload)))
        put(topic, payload, retain)
        if topic == topics.calibration and json.loads(payload).get("id") == 6:
            reader_put_6.set()

    def request(cmd):
        assert cmd == "calibration"
        cal = _cal(in_force["id"])
        if threading.current_thread() is main_poll:
            in_force["id"] = 6                  # the daemon applies #6 right after answering
            go_reader.set()
            reader_put_6.wait(1.0)              # the poll thread is held up before it publishes
        return cal

    b.put, b._request = recording_put, request
    go_reader = threading.Event()
    status = {"class": "STATUS", "calibration_id": 5, "board_stats": {"samples": 0}}
    main_poll = threading.Thread(target=b._health, args=(status, topics, None))

    def reader():
        go_reader.wait(5.0)
        b._record({"class": "CAL", "id": 6, "applied": True}, Decimator(1.0), topics)

    rd = threading.Thread(target=reader)
    main_poll.start()
    rd.start()
    main_poll.join(5.0)
    rd.join(5.0)
    cals = [p["id"] for t, p in sent if t == topics.calibration]
    assert sorted(cals) == [5, 6]
    assert cals[-1] == 6 and b.cal_id == 6, cals
    ev = [p for t, p in sent if t == topics.event("cal")]
    assert ev and ev[-1]["accel"]["stderr"] == _cal(6)["accel"]["stderr"]
