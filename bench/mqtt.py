"""The MQTT bridge on loopback: messages per second and end-to-end latency.

A stand-in daemon (tests/mosquitto.py's FakeDaemon: the stream and control sockets) feeds
an ``imucald mqtt`` process, which publishes to a Mosquitto broker started here; a
subscriber in this process receives.  Every record carries the Unix time the stand-in
wrote it, so the latency is stream socket -> bridge -> broker -> subscriber.

* throughput: N records written as fast as the bridge reads them, every one published
  (sample_rate_hz = the stream's rate, buffer N so none is dropped); messages/s from the
  first to the last received, per QoS; median over the repeats.
* latency: 200 records/s for D s (a 1 kHz daemon decimated to 200 Hz, say); median and
  95th percentile of the per-message latency, per QoS; the medians over the repeats.

Usage: python bench/mqtt.py [--repeats 3] [--count 20000] [--seconds 5]
Needs mosquitto (apt-get install mosquitto) and paho-mqtt (pip install '.[mqtt]').
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time

QOS = tuple(int(q) for q in os.environ.get("BENCH_QOS", "0,1,2").split(","))
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def run_once(qos, count, rate_hz, paced, seconds):
    import paho.mqtt.client as mqtt
    from tests.mosquitto import SID, Broker, FakeDaemon
    with tempfile.TemporaryDirectory() as d:
        # mosquitto 2.0.11's per-subscriber limits (20 in flight, 1000 queued) dropped most of
        # a fast QoS 2 flow for the subscriber here although the broker had taken every
        # message from the bridge: lifted, so that the subscriber sees what the bridge sent
        broker = Broker(os.path.join(d, "broker"), persistence=False, log_all=False,
                        global_extra="max_inflight_messages 0\nmax_queued_messages 1000000").start()
        got, lock = [], threading.Lock()
        sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        ready = threading.Event()
        sub.on_connect = lambda c, u, f, r, p: c.subscribe([(f"imucald/{SID}/imu", qos),
                                                            (f"imucald/{SID}/health", 0)])
        health = []
        sub.on_subscribe = lambda *a: ready.set()

        def on_message(c, u, m):
            now = time.time()
            if m.topic.endswith("/health"):
                health.append(json.loads(m.payload))
                return
            with lock:
                got.append((now, m.payload))
        sub.on_message = on_message
        sub.connect("127.0.0.1", broker.port)
        sub.loop_start()
        ready.wait(5)
        fake = FakeDaemon(d, rate_hz=rate_hz, paced=paced, count=count)
        cfg = os.path.join(d, "c.yaml")
        with open(cfg, "w") as fh:
            fh.write(f"mqtt:\n  host: 127.0.0.1\n  port: {broker.port}\n  qos: {qos}\n"
                     f"  sample_rate_hz: {rate_hz}\n  buffer: {max(count or 0, 1000)}\n"
                     f"  status_interval_s: 1\nlog:\n  level: {os.environ.get('BENCH_LOG', 'warning')}\n")
        bridge = subprocess.Popen([sys.executable, "-m", "imucald.cli", "mqtt", "--config", cfg,
                                   "--runtime-dir", d], cwd=ROOT)
        t0 = time.monotonic()
        limit = seconds if paced else 120
        want = count if count else None
        while time.monotonic() - t0 < limit + 10:
            with lock:
                n = len(got)
            if want and n >= want:
                break
            if paced and time.monotonic() - t0 > seconds + 1.5:
                break
            time.sleep(0.05)
        bridge.terminate()
        bridge.wait(10)
        fake.close()
        sub.loop_stop()
        broker.stop()
    recs = [(t, json.loads(p)) for t, p in got]
    if os.environ.get("BENCH_DEBUG") and health:
        print(health[-1]["bridge"], file=sys.stderr)
    return recs


def throughput(qos, count):
    recs = run_once(qos, count, 1000.0, False, None)
    ts = [t for t, _ in recs]
    seqs = [r["seq"] for _, r in recs]
    rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 else float("nan")
    return rate, len(recs), len(seqs) - len(set(seqs))


def latency(qos, seconds):
    recs = run_once(qos, None, 200.0, True, seconds)
    lat = sorted((t - r["wall"]) * 1e3 for t, r in recs[50:])      # after the start-up
    med = statistics.median(lat)
    p95 = lat[int(0.95 * (len(lat) - 1))]
    return med, p95, len(recs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--count", type=int, default=20000)
    ap.add_argument("--seconds", type=float, default=5.0)
    a = ap.parse_args(argv)
    import paho.mqtt                               # noqa: F401  (the mqtt extra)
    from tests.mosquitto import find_mosquitto
    if find_mosquitto()[0] is None:
        print(find_mosquitto()[1])
        return 1
    print(f"MQTT bridge on loopback (mosquitto, {a.repeats} repeats, medians)")
    for qos in QOS:
        rs = [throughput(qos, a.count) for _ in range(a.repeats)]
        print(f"  QoS {qos}: {statistics.median(r[0] for r in rs):8.0f} messages/s "
              f"({a.count} records as fast as read; received {min(r[1] for r in rs)}..{max(r[1] for r in rs)}, "
              f"duplicates {max(r[2] for r in rs)})")
    for qos in QOS:
        ls = [latency(qos, a.seconds) for _ in range(a.repeats)]
        print(f"  QoS {qos}: latency stream -> subscriber median {statistics.median(x[0] for x in ls):.2f} ms, "
              f"p95 {statistics.median(x[1] for x in ls):.2f} ms (200 msg/s for {a.seconds:g} s, "
              f"{min(x[2] for x in ls)} messages)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
