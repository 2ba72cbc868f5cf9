"""A throwaway Mosquitto broker on loopback for the MQTT tests and bench/mqtt.py.

The broker is Debian's ``mosquitto`` package: ``make test`` (.ci/run) installs it when it
runs as root with apt; elsewhere the tests skip, saying so."""
import json
import os
import shutil
import socket
import subprocess
import threading
import time

__all__ = ["find_mosquitto", "free_port", "Broker", "stop_all", "make_tls_files", "FakeDaemon", "SID"]

SID = "0123456789ab"

#: brokers started and not yet stopped (tests stop them all at teardown: stop_all)
LIVE = []


def _die_with_parent():
    """In the broker's child process: SIGTERM when the test process dies (Linux
    PR_SET_PDEATHSIG), so a killed pytest run leaves no broker behind."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, 15)     # PR_SET_PDEATHSIG, SIGTERM
    except (OSError, AttributeError):
        pass


def stop_all():
    for b in list(LIVE):
        b.stop()


def find_mosquitto():
    """(path, None) or (None, why not)."""
    for p in (shutil.which("mosquitto"), "/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto"):
        if p and os.access(p, os.X_OK):
            return p, None
    return None, ("mosquitto not found (Debian package 'mosquitto'; `make test` installs it when "
                  "run as root with apt-get)")


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Broker:
    """``mosquitto -c conf`` on 127.0.0.1:port; ``extra`` lines go into the listener's
    config (TLS, password file).  Persistence (on by default) keeps the subscriber's
    session and its queued QoS 1 messages across a restart."""

    def __init__(self, workdir, port=None, extra="", persistence=True, log_all=True, global_extra=""):
        self.exe, why = find_mosquitto()
        if self.exe is None:
            raise RuntimeError(why)
        self.dir = str(workdir)
        os.makedirs(self.dir, exist_ok=True)
        self.port = port or free_port()
        self.conf = os.path.join(self.dir, "mosquitto.conf")
        anon = "false" if "password_file" in extra else "true"
        with open(self.conf, "w") as fh:
            fh.write(f"{global_extra}\nper_listener_settings false\nallow_anonymous {anon}\n"
                     f"persistence {'true' if persistence else 'false'}\n"
                     f"persistence_location {self.dir}/\nautosave_interval 0\n"
                     f"log_dest file {self.dir}/mosquitto.log\nlog_type {'all' if log_all else 'error'}\n"
                     + ("user root\n" if os.geteuid() == 0 else "") 
                     + f"listener {self.port} 127.0.0.1\n{extra}\n")
        self.proc = None

    def start(self, timeout_s=10.0):
        self.proc = subprocess.Popen([self.exe, "-c", self.conf], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, preexec_fn=_die_with_parent)
        if self not in LIVE:
            LIVE.append(self)
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.proc.stderr.read().decode()[-500:]} "
                                   f"{self.log()[-500:]}")
            try:
                socket.create_connection(("127.0.0.1", self.port), 0.2).close()
                return self
            except OSError:
                time.sleep(0.02)
        raise RuntimeError(f"mosquitto did not listen on {self.port}")

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
        if self in LIVE:
            LIVE.remove(self)

    def log(self):
        try:
            with open(os.path.join(self.dir, "mosquitto.log")) as fh:
                return fh.read()
        except OSError:
            return ""


def make_tls_files(d):
    """A throwaway CA and a server certificate for 127.0.0.1/localhost with the openssl CLI:
    (ca.crt, server.crt, server.key) or None when openssl is missing."""
    ossl = shutil.which("openssl")
    if ossl is None:
        return None
    d = str(d)
    run = lambda *a: subprocess.run([ossl, *a], cwd=d, check=True, capture_output=True)
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1")     # fast to make
    run("req", "-x509", *ec, "-nodes", "-days", "2", "-subj", "/CN=imucald test CA",
        "-keyout", "ca.key", "-out", "ca.crt")
    run("req", *ec, "-nodes", "-subj", "/CN=localhost", "-keyout", "server.key",
        "-out", "server.csr")
    with open(os.path.join(d, "san.ext"), "w") as fh:
        fh.write("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
        "-days", "2", "-extfile", "san.ext", "-out", "server.crt")
    return tuple(os.path.join(d, f) for f in ("ca.crt", "server.crt", "server.key"))


class FakeDaemon:
    """The daemon's two sockets, served from threads: a stream of IMU records (t = seq /
    rate_hz; sent at that rate when paced, else as fast as the reader takes them; ``count``
    of them, else until close), each carrying ``wall``, the Unix time it was written; and a
    control socket answering status."""

    def __init__(self, d, rate_hz=200.0, paced=True, count=None):
        self.rt = str(d)
        self.rate_hz, self.seq, self.stop, self.extra = rate_hz, 0, threading.Event(), []
        self.paced, self.count = paced, count
        self.sid = SID
        self.srv = self._listen("imucald.sock")
        self.ctl = self._listen("control.sock")
        for f in (self._stream, self._control):
            threading.Thread(target=f, daemon=True).start()

    def _listen(self, name):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.bind(os.path.join(self.rt, name))
        s.listen(4)
        s.settimeout(0.2)
        return s

    def _accept(self, srv):
        while not self.stop.is_set():
            try:
                return srv.accept()[0]
            except socket.timeout:
                continue
            except OSError:         # closed by close()
                return None
        return None

    def _stream(self):
        while True:
            c = self._accept(self.srv)
            if c is None:
                return
            c.sendall(b'{"class":"VERSION","release":"0.1.0","proto_major":1,"proto_minor":0,'
                      b'"format":"ndjson","board":"mpu6050"}\n')
            t_next = time.monotonic()
            try:
                while not self.stop.is_set() and (self.count is None or self.seq < self.count):
                    while self.extra:
                        c.sendall((json.dumps(self.extra.pop(0)) + "\n").encode())
                    rec = {"class": "IMU", "seq": self.seq, "t": self.seq / self.rate_hz,
                           "acc_g": [0.0, 0.0, 1.0], "gyro_dps": [0.0, 0.0, 0.0], "still": True, "cal": 0,
                           "wall": time.time()}
                    c.sendall((json.dumps(rec) + "\n").encode())
                    self.seq += 1
                    if self.paced:
                        t_next += 1.0 / self.rate_hz
                        time.sleep(max(0.0, t_next - time.monotonic()))
                while not self.stop.is_set():       # all sent: stay connected
                    time.sleep(0.05)
            except OSError:
                pass
            c.close()

    def _control(self):
        while True:
            c = self._accept(self.ctl)
            if c is None:
                return
            with c:
                cmd = c.makefile("rb").readline().decode().strip()
                if cmd == "status":
                    r = {"class": "STATUS", "board": "mpu6050", "chips": {"accel": "mpu6050"},
                         "rate_hz": self.rate_hz, "bus": "fake", "poses": 3, "poses_needed": 25,
                         "coverage": 0.1, "calibration_id": 0, "samples": self.seq,
                         "board_stats": {"samples": self.seq, "gaps": 1, "missing": 7, "bus_faults": 2},
                         "sensor": {"id": self.sid, "status": "first"}}
                else:
                    r = {"class": "ERROR", "message": "unknown"}
                c.sendall((json.dumps(r) + "\n").encode())

    def close(self):
        self.stop.set()
        self.srv.close()
        self.ctl.close()
