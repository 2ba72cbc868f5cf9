"""The MQTT bridge against a real Mosquitto broker on loopback (started by each test):
round trip from the emulated daemon, broker restart mid-stream, password from a file, TLS.
Skips, saying why, where mosquitto or paho-mqtt is missing."""
import json
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

from imucald.daemon.config import load_config
from tests.mosquitto import SID, Broker, FakeDaemon, find_mosquitto, make_tls_files, stop_all


@pytest.fixture(autouse=True)
def _no_broker_left():
    """Every broker a test started is stopped, whether the test passed or not."""
    yield
    stop_all()
from tests.test_daemon import PY, ROOT, control, start_daemon, wait_for

mqtt = pytest.importorskip("paho.mqtt.client", reason="paho-mqtt is not installed (pip install '.[test]')")
MOSQ, WHY = find_mosquitto()
pytestmark = pytest.mark.skipif(MOSQ is None, reason=WHY or "")

class Sub:
    """A subscriber that keeps every message (topic, payload, retain, dup)."""

    def __init__(self, port, topics=("#",), client_id=None, tls_ca=None, auth=None, qos=1):
        self.msgs, self.lock = [], threading.Lock()
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id or "",
                             clean_session=client_id is None)
        if tls_ca:
            self.c.tls_set(ca_certs=tls_ca)
        if auth:
            self.c.username_pw_set(*auth)
        self.c.reconnect_delay_set(0.05, 0.5)
        self.subscribed = threading.Event()
        self.c.on_connect = lambda c, u, f, r, p: [c.subscribe(t, qos=qos) for t in topics]
        self.c.on_subscribe = lambda *a: self.subscribed.set()
        self.c.on_message = self._on
        self.c.connect("127.0.0.1", port, keepalive=5)
        self.c.loop_start()
        assert self.subscribed.wait(5), "the test's subscriber could not subscribe"

    def _on(self, c, u, m):
        with self.lock:
            self.msgs.append((m.topic, m.payload, m.retain, m.dup))

    def of(self, suffix):
        with self.lock:
            return [(json.loads(p) if p[:1] in (b"{", b"[") else p.decode()) for t, p, _, _ in self.msgs
                    if t.endswith(suffix)]

    def wait(self, cond, timeout=15.0):
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if cond():
                return True
            time.sleep(0.02)
        return False

    def close(self):
        self.c.disconnect()
        self.c.loop_stop()


def _status(rt, proc, timeout=60.0):
    """The daemon's status, once its control socket exists and listens (the socket file
    appears a moment before the daemon listens on it)."""
    wait_for(rt / "control.sock", proc)
    t0 = time.monotonic()
    while True:
        try:
            return control(rt, "status")
        except ConnectionRefusedError:
            if time.monotonic() - t0 > timeout:
                raise
            time.sleep(0.05)


def _cfg(tmp_path, port, **mq):
    lines = [f"  port: {port}", "  host: 127.0.0.1", "  status_interval_s: 0.3"]
    lines += [f"  {k}: {v}" for k, v in mq.items()]
    p = tmp_path / "imucald.yaml"
    p.write_text("mqtt:\n" + "\n".join(lines) + "\n")
    return p


def _bridge_thread(cfg_path, rt):
    from imucald.mqtt.bridge import Bridge
    cfg = load_config(str(cfg_path))
    b = Bridge(cfg, runtime_dir=str(rt))
    stop = threading.Event()
    t = threading.Thread(target=b.run, args=(stop,), daemon=True)
    t.start()
    return b, stop, t


def _refused_bridge(sub, cfg_path, rt):
    """Run a bridge that the broker must refuse: no connection, nothing published; returns
    its last connect error."""
    b, stop, t = _bridge_thread(cfg_path, rt)
    try:
        assert sub.wait(lambda: b.last_connect_error is not None, 60)
        assert b.stats["connects"] == 0 and b.stats["published"] == 0
        return b.last_connect_error
    finally:
        stop.set()
        t.join(10)


def test_round_trip_from_the_emulated_daemon(tmp_path):
    """Daemon (emulated MPU-6050, 20x time) -> bridge process -> broker -> subscriber:
    decimated samples, a calibration event with standard errors, health, retained status and
    Home Assistant discovery under the sensor's id; "offline" on a clean stop and as the
    last will of a killed bridge."""
    broker = Broker(tmp_path / "broker").start()
    # (a long duration: on a loaded machine the niced calibration worker may need a while)
    d, rt, st = start_daemon(tmp_path, "--speed", "20", "--duration", "900", "--seed", "2")
    sub = bridge = None
    try:
        sid = _status(rt, d)["sensor"]["id"]
        sub = Sub(broker.port, topics=("imucald/#", "homeassistant/#"))
        cfg = _cfg(tmp_path, broker.port, sample_rate_hz=20, discovery="true")
        cmd = [PY, "-m", "imucald.cli", "mqtt", "--config", str(cfg), "--runtime-dir", str(rt)]
        bridge = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True)
        # an applied calibration whose event carries its standard errors: the bridge adds them
        # when the calibration in force is still that one as it reads the event; on a loaded
        # machine it can read the stream so late that a newer one is already in force (that
        # event then has none), so the wait is for such an event, not for the first applied
        got_cal = sub.wait(lambda: any(c.get("applied") and "accel" in c
                                       for c in sub.of(f"{sid}/event/cal")), 180)
        # (conditions with generous bounds: they return as soon as met; a loaded machine is slow)
        sub.wait(lambda: any(h["calibration_id"] for h in sub.of(f"{sid}/health")), 60)
        sub.wait(lambda: sum(m["cal"] >= 1 and m["still"] for m in sub.of(f"{sid}/imu")) >= 20, 60)
        bridge.send_signal(signal.SIGTERM)
        assert bridge.wait(10) == 0
        err = bridge.stderr.read()
        assert got_cal, err
    finally:
        for p in (bridge, d):
            if p is not None and p.poll() is None:
                p.kill()
    imu = sub.of(f"imucald/{sid}/imu")
    assert len(imu) > 100
    seq = np.array([m["seq"] for m in imu])
    # 100 Hz decimated to 20 Hz on the stream's clock: the first sample of each 50 ms, never
    # two in one interval; a sample inside an interval only right after samples the bridge
    # did not see (its first, or after the daemon dropped a slow reader on a loaded machine)
    t = np.array([m["t"] for m in imu])
    k = np.floor(t / 0.05 + 1e-9)
    assert np.all(np.diff(k) >= 1), "two samples in one interval, or out of order"
    d = np.diff(seq)
    inside = np.flatnonzero(seq[1:] % 5 != 0)
    assert np.all(d[inside] != 5), "a sample inside an interval although its predecessor was published"
    assert np.mean(d == 5) > 0.9, np.unique(d, return_counts=True)
    assert all({"acc_g", "gyro_dps", "temp_c", "t", "time", "cal"} <= set(m) for m in imu)
    cal = [c for c in sub.of(f"{sid}/event/cal") if c.get("applied") and "accel" in c][0]
    assert cal["accel_heldout_rms_g"] < cal["accel_heldout_rms_before_g"]
    se = cal["accel"]["stderr"]
    assert set(se) == {"alpha", "scale", "bias_g"} and all(0 < s < 0.01 for s in se["bias_g"]), cal
    full = [f for f in sub.of(f"{sid}/calibration") if f["id"] == cal["id"]]
    assert full and full[-1]["accel"]["params"]["bias_g"]
    # after that calibration the published samples are corrected: |a| = 1 g when still
    still = np.array([m["acc_g"] for m in imu if m["still"] and m["cal"] >= cal["id"]])
    assert len(still) >= 20 and abs(np.median(np.linalg.norm(still, axis=1)) - 1) < 0.01
    health = sub.of(f"{sid}/health")
    assert health and health[-1]["rate_hz"] == 100.0 and health[-1]["calibration_id"] >= 1
    assert health[-1]["calibration_age_s"] is not None and health[-1]["faults"]["bus_faults"] == 0
    assert sub.of(f"{sid}/info")[0]["fingerprint"]["chips"]["mpu"]["chip"] == "mpu6050"
    disc = [m for m in sub.msgs if m[0].startswith(f"homeassistant/sensor/imucald_{sid}/")]
    assert len(disc) >= 8
    conf = json.loads(disc[-1][1])
    assert conf["device"]["sw_version"] == "0.1.0" and conf["device"]["identifiers"] == [f"imucald_{sid}"]
    assert conf["availability_topic"] == f"imucald/{sid}/status" and conf["unique_id"].startswith("imucald_")
    assert sub.of(f"{sid}/status")[0] == "online" and sub.of(f"{sid}/status")[-1] == "offline"
    sub.close()
    # a new subscriber gets the retained status; a killed bridge leaves its last will
    # (a long duration, killed below: 60 s at 5x ended the daemon after 12 s of wall time,
    # which the waits below, a bridge's start-up included, can outlast on a loaded machine)
    d2, rt2, _ = start_daemon(tmp_path / "second", "--speed", "5", "--duration", "3600")
    try:
        sid2 = _status(rt2, d2)["sensor"]["id"]
        late = Sub(broker.port, topics=(f"imucald/{sid}/status", f"imucald/{sid2}/status",
                                        f"imucald/{sid}/health", "homeassistant/#"))
        assert late.wait(lambda: late.of(f"{sid}/status") == ["offline"], 30)
        retained = lambda: {t for t, _, r, _ in list(late.msgs) if r}
        assert late.wait(lambda: f"imucald/{sid}/health" in retained() and sum(
            t.startswith(f"homeassistant/sensor/imucald_{sid}/") for t in retained()) >= 8, 30), retained()
        b2 = subprocess.Popen([PY, "-m", "imucald.cli", "mqtt", "--config", str(cfg), "--runtime-dir",
                               str(rt2)], cwd=ROOT, stderr=subprocess.DEVNULL)
        assert late.wait(lambda: "online" in late.of(f"{sid2}/status"), 60)
        b2.kill()
        b2.wait()
        assert late.wait(lambda: late.of(f"{sid2}/status")[-1:] == ["offline"], 30)
        late.close()
    finally:
        d2.kill()
        broker.stop()


def test_broker_restart_mid_stream_reconnects_drops_oldest_and_counts(tmp_path):
    """The broker goes away for 0.6 s at 200 samples/s with a 20-message buffer: the bridge
    reconnects, the subscriber's persistent QoS 1 session gets every sample the bridge kept,
    none twice, and the ones it dropped are exactly the ones counted."""
    broker = Broker(tmp_path / "broker").start()
    fake = FakeDaemon(tmp_path)
    sub = Sub(broker.port, topics=(f"imucald/{SID}/imu", f"imucald/{SID}/event/#"), client_id="test-sub")
    b, stop, t = _bridge_thread(_cfg(tmp_path, broker.port, sample_rate_hz=200, buffer=20, qos=1), tmp_path)
    try:
        assert sub.wait(lambda: len(sub.of("/imu")) > 50, 60)
        broker.stop()
        time.sleep(0.6)
        broker.start()
        assert sub.wait(lambda: b.stats["connects"] >= 2, 60), broker.log()[-2000:]
        fake.extra.append({"class": "GAP", "seq": fake.seq + 1, "missing": 3})
        sub.wait(lambda: sub.of("/event/gap"), 60)          # a condition, not a 0.5 s sleep
        outages = b.stats["disconnects"]
    finally:
        stop.set()
        t.join(10)
        fake.close()
    fresh = lambda: [json.loads(p)["seq"] for t, p, _, dup in sub.msgs if t.endswith("/imu") and not dup]
    sub.wait(lambda: len(set(fresh())) + b.buf.dropped_by.get("imu", 0) >= b.stats["samples_out"], 60)
    time.sleep(0.2)
    # the broker itself may redeliver to the subscriber, after its own restart, what it had
    # sent just before (flagged DUP, QoS 1's at-least-once); the bridge must never publish
    # one sample twice: a sample it sent twice would reach the subscriber without that flag
    seqs = fresh()
    sub.close()
    broker.stop()
    assert len(seqs) == len(set(seqs)), "duplicated samples"
    assert b.stats["disconnects"] >= 1 and b.stats["connects"] >= 2
    dropped = b.buf.dropped_by.get("imu", 0)
    assert dropped > 0, "the outage should have overflowed a 20-message buffer"
    one_outage = outages == 1
    assert b.stats["dropped"] == b.buf.dropped
    # every sample the bridge decimated in was either delivered or counted as dropped
    assert b.stats["unsent_at_stop"] == 0 and b.stats["lost_in_flight"] == 0
    assert len(seqs) + dropped == b.stats["samples_out"]
    # the dropped ones are the oldest of the outage: one contiguous hole in the sequence
    missing = sorted(set(range(min(seqs), max(seqs) + 1)) - set(seqs))
    assert len(missing) == dropped
    if one_outage:      # (a loaded machine may see a second one)
        assert missing[-1] - missing[0] == dropped - 1
    gaps = sub.of("/event/gap")
    assert gaps and gaps[0]["missing"] == 3 and b.stats["gaps"] == 1 and b.stats["missing_samples"] == 3


def test_username_and_password_from_a_file(tmp_path):
    broker_dir = tmp_path / "broker"
    broker_dir.mkdir()
    pw = broker_dir / "passwd"
    subprocess.run(["mosquitto_passwd", "-b", "-c", str(pw), "imu", "s3cret pass"], check=True,
                   capture_output=True)
    broker = Broker(broker_dir, extra=f"password_file {pw}").start()
    fake = FakeDaemon(tmp_path)
    secret = tmp_path / "mqtt-password"
    secret.write_text("s3cret pass\n")
    os.chmod(secret, 0o600)
    sub = Sub(broker.port, topics=(f"imucald/{SID}/status",), auth=("imu", "s3cret pass"))
    b, stop, t = _bridge_thread(_cfg(tmp_path, broker.port, username="imu", password_file=str(secret)),
                                tmp_path)
    try:
        assert sub.wait(lambda: "online" in sub.of("/status"), 60), broker.log()[-1500:]
    finally:
        stop.set()
        t.join(10)
    assert b.stats["connects"] >= 1
    # the wrong password: refused, nothing published
    secret.write_text("wrong\n")
    try:
        _refused_bridge(sub, _cfg(tmp_path, broker.port, username="imu", password_file=str(secret)), tmp_path)
    finally:
        fake.close()
        sub.close()
        broker.stop()


def test_tls_with_a_private_ca(tmp_path):
    files = make_tls_files(tmp_path)
    if files is None:
        pytest.skip("openssl CLI not found: cannot make a throwaway CA")
    ca, crt, key = files
    broker = Broker(tmp_path / "broker", extra=f"cafile {ca}\ncertfile {crt}\nkeyfile {key}").start()
    fake = FakeDaemon(tmp_path)
    sub = Sub(broker.port, topics=(f"imucald/{SID}/imu",), tls_ca=ca)
    b, stop, t = _bridge_thread(_cfg(tmp_path, broker.port, tls="true", ca_file=ca), tmp_path)
    try:
        assert sub.wait(lambda: len(sub.of("/imu")) >= 5, 60), broker.log()[-1500:]
    finally:
        stop.set()
        t.join(10)
    # a broker whose certificate the given CA did not sign: no connection
    (tmp_path / "other").mkdir()
    other = make_tls_files(tmp_path / "other")
    try:
        err = _refused_bridge(sub, _cfg(tmp_path, broker.port, tls="true", ca_file=other[0]), tmp_path)
        assert "certificate verify failed" in err, err
    finally:
        fake.close()
        sub.close()
        broker.stop()


def test_configuration_errors_are_one_line(tmp_path):
    """A missing password file, a CA without TLS, a wildcard prefix: one line, exit 78."""
    cases = [("mqtt:\n  username: u\n  password_file: /nonexistent/pw\n", "mqtt.password_file"),
             ("mqtt:\n  ca_file: /x.crt\n", "mqtt.tls is false"),
             ("mqtt:\n  topic_prefix: a/#\n", "wildcard"),
             ("mqtt:\n  qos: 3\n", "mqtt.qos")]
    for text, want in cases:
        p = tmp_path / "c.yaml"
        p.write_text(text)
        r = subprocess.run([PY, "-m", "imucald.cli", "mqtt", "--config", str(p), "--runtime-dir",
                            str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=30)
        assert r.returncode == 78 and want in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_swapped_sensor_gets_its_own_topics(tmp_path):
    """The daemon now reads another sensor (a swapped board): the old id's status turns
    offline (retained) and the samples go on under the new id."""
    broker = Broker(tmp_path / "broker").start()
    fake = FakeDaemon(tmp_path)
    sub = Sub(broker.port, topics=("imucald/#",))
    b, stop, t = _bridge_thread(_cfg(tmp_path, broker.port, sample_rate_hz=50), tmp_path)
    new = "fedcba987654"
    try:
        assert sub.wait(lambda: len(sub.of(f"{SID}/imu")) > 5, 60)
        fake.sid = new
        assert sub.wait(lambda: len(sub.of(f"{new}/imu")) > 5 and "online" in sub.of(f"{new}/status"), 60)
    finally:
        stop.set()
        t.join(10)
        fake.close()
    assert sub.of(f"{SID}/status")[-1] == "offline"
    n_old = len(sub.of(f"{SID}/imu"))
    time.sleep(0.3)
    assert len(sub.of(f"{SID}/imu")) == n_old
    sub.close()
    broker.stop()


def test_the_base_install_never_imports_paho(tmp_path):
    """Without paho-mqtt the daemon and the other commands work, and `imucald mqtt` says
    what to install in one line (exit 69)."""
    block = ("import sys; sys.modules['paho'] = None; sys.modules['paho.mqtt'] = None; "
             "sys.modules['paho.mqtt.client'] = None; from imucald.cli import main; ")
    r = subprocess.run([PY, "-c", block + "import imucald.daemon.run, imucald.mqtt.topics; "
                        "sys.exit(main(['run', '--emulate', '--duration', '1', '--speed', '10', "
                        f"'--state-dir', '{tmp_path}/s', '--runtime-dir', '{tmp_path}/r']))"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([PY, "-c", block + f"sys.exit(main(['mqtt', '--runtime-dir', '{tmp_path}']))"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 69 and "pip install 'imucald[mqtt]'" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
