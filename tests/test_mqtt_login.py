"""The bridge and a broker that refuses its login (issue 22): backoff, then exit 78.

The same behaviour is checked under systemd by tests/test_system.py; this one runs in the
plain suite (a local Mosquitto, ~3 s)."""
import logging
import os
import subprocess
import threading
import time

import pytest

from imucald.daemon.config import load_config
from tests.mosquitto import Broker, FakeDaemon, find_mosquitto

pytestmark = pytest.mark.skipif(find_mosquitto()[0] is None, reason=find_mosquitto()[1] or "")
pytest.importorskip("paho.mqtt.client")


class Times(logging.Handler):
    def __init__(self):
        super().__init__()
        self.refused = []

    def emit(self, rec):
        if "refused the connection" in rec.getMessage():
            self.refused.append(time.monotonic())


def test_a_refused_login_backs_off_and_ends_with_78(tmp_path):
    """A wrong password: the refusals come 0.1, 0.2, 0.4, 0.8 s apart (doubling: the gap between
    refusals is the delay plus one connect round trip on loopback, < 50 ms) and the 5th ends the
    bridge with a ConfigError (exit 78) naming the setting.  Breakage caught: the delay reset on
    every TCP connect (refusals ~0.1 s apart, ~10 a second) and no end."""
    from imucald.errors import EX_CONFIG
    from imucald.mqtt import bridge as mb
    from imucald.mqtt.bridge import Bridge
    LOGIN_REFUSALS = getattr(mb, "LOGIN_REFUSALS", 5)    # the documented 5 (README, issue 22)
    bd = tmp_path / "broker"
    bd.mkdir()
    pw = bd / "passwd"
    subprocess.run(["mosquitto_passwd", "-b", "-c", str(pw), "imu", "right"], check=True, capture_output=True)
    broker = Broker(bd, extra=f"password_file {pw}").start()
    fake = FakeDaemon(tmp_path)
    secret = tmp_path / "mqtt-password"
    secret.write_text("wrong\n")
    os.chmod(secret, 0o600)
    cfg = tmp_path / "imucald.yaml"
    cfg.write_text(f"mqtt:\n  host: 127.0.0.1\n  port: {broker.port}\n  username: imu\n"
                   f"  password_file: {secret}\n  status_interval_s: 0.3\n")
    h = Times()
    logging.getLogger("imucald.mqtt").addHandler(h)
    out = {}

    def run():
        try:
            out["rc"] = b.run(stop)
        except Exception as e:          # the CLI turns a UserError into its exit code
            out["error"] = e
    try:
        b = Bridge(load_config(str(cfg)), runtime_dir=str(tmp_path))
        stop = threading.Event()
        t = threading.Thread(target=run, daemon=True)
        t.start()
        t.join(20)
        alive = t.is_alive()
        stop.set()
        t.join(10)
    finally:
        logging.getLogger("imucald.mqtt").removeHandler(h)
        fake.close()
        broker.stop()
    assert not alive, f"still retrying after 20 s: {len(h.refused)} refusals"
    e = out.get("error")
    assert e is not None and e.exit_code == EX_CONFIG and "mqtt.password_file" in str(e), out
    assert len(h.refused) == LOGIN_REFUSALS, h.refused
    gaps = [b - a for a, b in zip(h.refused, h.refused[1:])]
    for i, g in enumerate(gaps):
        delay = 0.1 * 2 ** i
        assert delay <= g < delay + 0.5, gaps          # 0.5 s: a loaded CI machine's slack
    assert b.stats["connects"] == 0 and b.stats["published"] == 0
