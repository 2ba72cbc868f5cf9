"""The daemon: board -> pipeline -> sinks, with control, persistence, signals, systemd.

Single-threaded sampling loop.  Calibration runs in a worker process started
per job (daemon/worker.py: supervised, timed out, gone with the daemon; none
while idle), so the sampler never waits on it; state files are written by one
background thread (daemon/persist.py: an fsync on an SD card can take tens of
milliseconds, a read-only directory is retried while the state stays in memory).
"""
from __future__ import annotations

import errno
import logging
import math
import os
import signal
import time
from typing import Any, Dict, Optional

from ..errors import AlreadyRunning, CannotCreate, UserError
from .notify import notify, watchdog_period_s
from .pipeline import Pipeline, batch_period_s
from .state import load_calibration, load_poses, save_calibration, save_poses

__all__ = ["Daemon", "LOCK_FILE"]

#: held with flock in the runtime and state directories while a daemon runs
LOCK_FILE = "imucald.lock"

#: a sensor with no fresh sample for this long is stalled: one log line, and under systemd's
#: watchdog the daemon stops feeding it and asks for the watchdog action at once
#: (WATCHDOG=trigger, sd_notify(3)), so systemd restarts it STALL_S (+ RestartSec=) after the
#: outage instead of 2 x WatchdogSec.  Longer than any outage the chip's FIFO rides out
#: (1024 bytes at 200 Hz x 12 bytes: 0.4 s) and than a re-initialisation (0.5 s of faults).
STALL_S = 3.0

#: sampling that loses more than LOSS_SHARE of a LOSS_EVERY_S stretch's samples (the chip's
#: FIFO overflowed: the host read it too late) is said in the log, at most once a stretch, and
#: at the stop for the stretch since (of LOSS_FINAL_S or more: a run shorter than a stretch,
#: e.g. the quick start's 30 s, lost 19 % in silence under load, said only by status)
LOSS_EVERY_S, LOSS_SHARE, LOSS_FINAL_S = 60.0, 0.01, 5.0

log = logging.getLogger("imucald")


def loss_warning(got: int, lost: int, resets: int, reinits: int, span_s: float,
                 speed: float = 1.0) -> Optional[str]:
    """The log line for a stretch of ``span_s`` wall seconds in which the board delivered
    ``got`` samples and lost ``lost``, with ``resets`` FIFO resets (overflows: read too late)
    and ``reinits`` re-initialisations (bus faults, a chip reset), or None below LOSS_SHARE.
    ``speed``: an emulated board's clock rate (its FIFO then lasts ``speed`` times less)."""
    if lost <= LOSS_SHARE * (got + lost):
        return None
    causes = []
    if resets:
        why = (f"--speed {speed:g} asks more than this machine sustains, the emulated FIFO lasting "
               f"{speed:g} times less" if speed > 1 else "a loaded or throttled host")
        causes.append(f"{resets} FIFO resets: the sensor is read too late, {why}")
    if reinits:
        causes.append(f"{reinits} re-initialisations after bus faults or a chip reset: check the "
                      f"wiring and power")
    return (f"sampling lost {100.0 * lost / (got + lost):.0f}% of the samples of the last {span_s:.0f} s "
            f"({'; '.join(causes) or 'cause not recorded'}); a pose needs an unbroken still run, so "
            f"fewer are found")


class Daemon:
    """Runs ``board`` (on ``bus``; ``desc`` says which, for the log) until stopped.

    The board is built by the caller (the CLI's board factory, real or emulated):
    the daemon does not know whether its chips are real.
    """

    def __init__(self, cfg: Dict[str, Dict[str, Any]], board, bus, desc: str,
                 duration_s: Optional[float] = None, echo: bool = False,
                 config_path: Optional[str] = None, overrides=None):
        self.cfg, self.duration_s, self.echo, self.config_path = cfg, duration_s, echo, config_path
        #: (key, value, flag) given on the command line: they outlive every reload
        self.overrides = list(overrides or [])
        self.board, self.bus, self.desc = board, bus, desc
        self.stop = False
        self.reload = False

    # -- setup --------------------------------------------------------------------------
    def _dirs(self):
        sd, rd = self.cfg["state"]["directory"], self.cfg["runtime"]["directory"]
        for d, key in ((sd, "state.directory"), (rd, "runtime.directory")):
            try:
                os.makedirs(d, exist_ok=True)
            except OSError as e:
                raise CannotCreate(f"{key}: cannot create {d}: {e.strerror} (run as the service, or "
                                   f"give --state-dir/--runtime-dir you can write)") from None
            if not os.access(d, os.W_OK):
                raise CannotCreate(f"{key}: {d} is not writable by this user")
        return sd, rd

    def _path(self, rd: str, p: str) -> str:
        return p if os.path.isabs(p) else os.path.join(rd, p)

    def _lock(self, d: str, key: str) -> None:
        """Hold ``d/imucald.lock`` (flock) for the daemon's life: a second instance on the
        same directory exits (75) instead of taking the sockets or the state files."""
        import fcntl
        path = os.path.join(d, LOCK_FILE)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as e:
            raise CannotCreate(f"{key}: cannot create the lock file {path}: {e.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            other = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise AlreadyRunning(f"{key}: another imucald (pid {other}) holds {path}: stop it first "
                                 f"(systemctl stop imucald) or give this one another "
                                 f"--runtime-dir/--state-dir") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._lock_fds.append(fd)

    def run(self) -> int:
        from .unixsock import check_socket_path
        cfg = self.cfg
        sd, rd = self._dirs()
        o, c = cfg["output"], cfg["control"]
        self._lock_fds: list = []
        try:
            self._lock(rd, "runtime.directory")
            if os.path.realpath(sd) != os.path.realpath(rd):
                self._lock(sd, "state.directory")
            # after the locks: a second instance on these directories is named by them (its
            # pid); a live socket elsewhere (an absolute path) by check_socket_path
            check_socket_path(self._path(rd, o["socket"]), "output.socket")
            check_socket_path(self._path(rd, c["socket"]), "control.socket")
            self._state_lock_fd = self._lock_fds[-1]     # the state directory's (_relock_state)
        except BaseException:
            for fd in self._lock_fds:
                os.close(fd)
            raise
        signal.signal(signal.SIGTERM, self._on_stop)
        signal.signal(signal.SIGINT, self._on_stop)
        signal.signal(signal.SIGHUP, self._on_hup)
        if getattr(self, "early_hup", None):       # one that came during start-up (cli/service.py)
            self.reload = True
        try:
            return self._run(sd, rd)
        finally:
            self._shutdown()

    def _run(self, sd: str, rd: str) -> int:
        from .control import ControlServer
        from .outputs import FifoSink, SocketSink
        cfg = self.cfg
        log.info("imucald starting: %s", self.desc)
        self.board.start()                                       # identifies the chips first
        chips = self.board.chips()
        log.info("found %s", ", ".join(f"{k} {v.upper()}" for k, v in self.board.chips().items()))
        from .persist import StateWriter
        from .state import remove_stale_temporaries
        from .worker import WorkerRunner
        if remove_stale_temporaries(sd):
            log.info("removed the temporary files an earlier run left in %s (killed mid-write)", sd)
        self.writer = StateWriter(self._save, sd)
        self.worker = WorkerRunner(cfg["calibration"]["timeout_s"])
        self.pipe = Pipeline(cfg, self.board.name, self.board.rate_hz, self.board.has_mag,
                             executor=self.worker, persist=self._persist, chips=chips,
                             has_acc=self.board.has_acc)
        self.pipe.use_noise_file(cfg["noise"]["file"])
        self.pipe.use_orientation(cfg["output"]["orientation"], self.board.has_acc,   # issue 26
                                  getattr(self.board, "gyro_range_dps", None))
        from .sensors import adopt_sensor
        self.fingerprint = self.board.fingerprint()
        self.sensor = adopt_sensor(sd, self.fingerprint)     # a swapped board: its own files
        sid = self.sensor["id"]
        log.info("sensor %s (%s)", sid, _fp_text(self.fingerprint))
        self.pipe.applied = self.pipe.applied.replace(sensor=sid)
        cal = load_calibration(sd, self.board.name, chips, sid)
        if cal is not None and not cal.sensor:
            cal = cal.replace(sensor=sid)          # made before fingerprints: adopted
        if cal is not None:
            self.pipe.applied = cal
            log.info("loaded calibration #%d (%s)", cal.id, cal.created)
        ps = load_poses(sd, board=self.board.name)
        if ps is not None and len(ps):
            self.pipe.acc.load(ps)
            self.pipe.next_cal_added = 0
            log.info("resumed %d poses from %s", len(ps), os.path.join(sd, "poses.csv"))
        tl = load_poses(sd, "thermal.csv", board=self.board.name)
        if tl is not None and len(tl):
            self.pipe.thermal_log.load(tl)
            log.info("resumed %d still intervals over %.1f degC for the thermal terms from %s",
                     len(self.pipe.thermal_log), self.pipe.thermal_log.span_c(), os.path.join(sd, "thermal.csv"))
        o, c = cfg["output"], cfg["control"]
        self.sinks: list = []
        self.sinks += [SocketSink(self._path(rd, o["socket"]), o["format"], self.board.name,
                                 o["socket_mode"], o["socket_group"], o["client_buffer_bytes"])]
        if o["fifo"]:
            self.sinks.append(FifoSink(self._path(rd, o["fifo"]), o["format"], self.board.name,
                                       o["socket_mode"], o["socket_group"], o["client_buffer_bytes"]))
        for sk in self.sinks:
            sk.chips = self.board.chips()
            sk.orientation_off = self.pipe.orientation_off
        self.control = ControlServer(self._path(rd, c["socket"]), self._command, c["socket_mode"],
                                     c["socket_group"])
        log.info("streaming %s on %s%s; control on %s", o["format"], self.sinks[0].path,
                 f" and {self.sinks[1].path}" if len(self.sinks) > 1 else "", self.control.path)
        return self._loop()

    # -- the loop -------------------------------------------------------------------------
    def _loop(self) -> int:
        b, pipe = self.board, self.pipe
        batch_s = batch_period_s(self.cfg["sensor"]["batch_s"], b.rate_hz)
        wd = watchdog_period_s()
        ready = stalled = False
        last_status = last_wd = -1e9
        last_fresh = time.monotonic()
        t_start = b.clock.now()
        st = b.stats
        loss0 = (last_fresh, st.samples, st.missing, st.fifo_resets, st.reinits)
        while not self.stop:
            batch = b.read_batch(batch_s=batch_s)
            data = pipe.process(batch)
            for s in self.sinks:
                s.write(data)
            self.control.poll()
            now = time.monotonic()
            if self.echo and data:
                self._echo(data, now)
            if len(batch):
                if stalled:
                    stalled = False
                    log.warning("the sensor is back after %.1f s without a sample", now - last_fresh)
                last_fresh = now
                if not ready:
                    notify("READY=1", f"STATUS={self._status_line()}")
                    log.info("first valid sample: ready")
                    ready = True
            if ready and not stalled and now - last_fresh >= STALL_S:
                stalled = True
                self._stalled(now - last_fresh, wd is not None)
            if wd and now - last_wd >= wd and not stalled and now - last_fresh < min(2 * wd, STALL_S):
                notify("WATCHDOG=1")                        # only while fresh samples arrive
                last_wd = now
            if now - last_status >= 1.0:
                notify(f"STATUS={self._status_line()}")
                last_status = now
            if now - loss0[0] >= LOSS_EVERY_S:
                loss0 = self._say_loss(loss0, now)
            if self.reload or self._reloading is not None:
                self._reload()
            if self.duration_s is not None and b.clock.now() - t_start >= self.duration_s:
                break
        if time.monotonic() - loss0[0] >= LOSS_FINAL_S:
            self._say_loss(loss0, time.monotonic())
        notify("STOPPING=1")
        return 0

    def _say_loss(self, loss0: tuple, now: float) -> tuple:
        """The loss warning (:func:`loss_warning`) for the stretch since ``loss0`` (its start,
        monotonic s, and the board's counters then), logged when it lost more than LOSS_SHARE;
        returns the next stretch's start."""
        st = self.board.stats
        msg = loss_warning(st.samples - loss0[1], st.missing - loss0[2], st.fifo_resets - loss0[3],
                           st.reinits - loss0[4], now - loss0[0], getattr(self.board.clock, "speed", 1.0))
        if msg:
            log.warning("%s", msg)
        return (now, st.samples, st.missing, st.fifo_resets, st.reinits)

    def _echo(self, data: bytes, now: float) -> None:
        """--echo (ndjson or csv; cmd_run refuses it for binary): every event line of the batch
        (CAL, GAP: a JSON object other than a sample, or a CSV '# ' comment) and the last
        sample line once a second.  Printing one line a second alone missed most CAL events."""
        lines = data.split(b"\n")[:-1]
        is_event = [ln.startswith(b"# ") or (ln.startswith(b"{") and not ln.startswith(b'{"class":"IMU"'))
                    for ln in lines]
        out = [ln for ln, e in zip(lines, is_event) if e]
        samples = [ln for ln, e in zip(lines, is_event) if not e]
        if samples and now - getattr(self, "_last_echo", 0) >= 1.0:
            self._last_echo = now
            out.append(samples[-1])
        for ln in out:
            print(ln.decode("utf-8", "replace"), flush=True)

    def _stalled(self, idle_s: float, watchdog: bool) -> None:
        """No fresh sample for ``idle_s``: say so (once per stall), and under the watchdog
        stop feeding it and trigger it (systemd restarts the service: Restart=on-failure)."""
        st = self.board.stats
        log.error("no sample from the sensor for %.1f s (bus faults %d, last fault: %s): %s", idle_s,
                  st.bus_faults, getattr(self.board, "last_fault", None) or "none",
                  "stopped feeding the watchdog; systemd restarts the service" if watchdog else
                  "check the wiring and power; sampling resumes when it answers")
        if watchdog:
            notify("WATCHDOG=trigger", f"STATUS=sensor stalled: no sample for {idle_s:.0f} s, "
                   f"bus faults {st.bus_faults}")

    def _status_line(self) -> str:
        p = self.pipe
        ap = p.applied
        age = ""
        if ap.id and p.applied_t_s is not None:
            age = f", age {p.t_last - p.applied_t_s:.0f} s"
        cal = f"cal #{ap.id}{age}" if ap.id else "uncalibrated"
        if getattr(self, "sensor", {}).get("status") == "changed" and not ap.id:
            cal += f" (new sensor {self.sensor['id']}, was {self.sensor['previous']})"
        return (f"{self.board.name} {self.board.rate_hz:g} Hz, poses {len(p.acc)}/"
                f"{self.cfg['calibration']['min_poses']}, {cal}, bus faults {self.board.stats.bus_faults}")

    # -- control ---------------------------------------------------------------------------
    def _command(self, cmd: str) -> Dict[str, Any]:
        p = self.pipe
        if cmd == "status":
            d = {"class": "STATUS", "board": self.board.name, "chips": self.board.chips(),
                 "rate_hz": self.board.rate_hz,
                 "bus": self.bus.name, **p.status(), "board_stats": self.board.stats.as_dict(),
                 "sensor": {**self.sensor, "fingerprint": self.fingerprint},
                 "bus_stats": self.bus.stats.as_dict(),
                 "clients": len(self.sinks[0].clients), "clients_dropped": self.sinks[0].dropped,
                 "clients_refused": self.sinks[0].refused,
                 "state": self.writer.status(), "control": self.control.stats(),
                 "worker": {"running": self.worker.running(), "started": self.worker.started,
                            "died": self.worker.died, "timeouts": self.worker.timeouts}}
            return d
        if cmd == "calibration":
            # the calibration in force with its standard errors and quality figures (what the
            # calibration file holds, less the poses it was fitted on)
            d = p.applied.to_dict()
            d.pop("poses_used", None)
            return {"class": "CALIBRATION", **d}
        if cmd == "poses":
            ps = p.acc.pose_set()
            return {"class": "POSES", "count": len(ps),
                    "poses": [_pose_json(ps, i) for i in range(len(ps))]}
        if cmd == "coverage":
            return {"class": "COVERAGE", **p.acc.coverage(),
                    **({"mag_coverage": p.reservoir.coverage()} if p.reservoir is not None else {})}
        if cmd == "recalibrate":
            from .pipeline import MIN_FIT_POSES
            if p.has_acc and len(p.acc) < MIN_FIT_POSES:
                return {"class": "ERROR", "message": (
                    f"only {len(p.acc)} poses: the 9-parameter accelerometer fit scored by "
                    f"leave-one-pose-out needs at least {MIN_FIT_POSES}; place the sensor still in "
                    f"{MIN_FIT_POSES - len(p.acc)} more orientations")}
            if p.pending is not None:
                return {"class": "RECALIBRATE", "started": False}
            return {"class": "RECALIBRATE", "started": p.request_calibration()}
        if cmd == "reset":
            log.info("poses reset by a control request (%d dropped; the calibration in force "
                     "stays)", len(p.acc))
            p.acc.clear()
            p.next_cal_added = 0
            self._persist("poses", p.acc.pose_set())
            return {"class": "RESET", "poses": 0}
        if cmd == "reload":
            self.reload = True
            return {"class": "RELOAD", "scheduled": True}
        raise AssertionError(cmd)

    _reloading = None

    def _reload(self) -> None:
        """SIGHUP / reload: re-read the configuration with the command line's overrides;
        every reloadable key takes effect at once, the others are named as needing a
        restart.  A file that does not load leaves the running configuration as it is.
        The file is parsed on a thread of its own (its size, depth and aliases bounded by
        yamlsafe), so sampling, the sockets and the signals carry on meanwhile; the loop
        applies the result once the thread is done."""
        import threading
        t = self._reloading
        if t is None:
            self.reload = False
            box: list = []
            t = threading.Thread(target=self._reload_parse, args=(box,), name="imucald-reload",
                                 daemon=True)
            t.box = box
            self._reloading = t
            t.start()
            return
        if t.is_alive():
            return
        self._reloading = None
        if t.box:
            self._reload_apply(t.box[0])

    def _reload_parse(self, box: list) -> None:
        from .config import apply_overrides, load_config
        try:
            new = load_config(self.config_path)
            apply_overrides(new, self.overrides, self.config_path)
            box.append(new)
        except UserError as e:
            log.error("reload failed, keeping the running configuration: %s", " ".join(str(e).split()))
        except Exception as e:          # a reload must never stop the sampler
            log.error("reload failed (%s: %s), keeping the running configuration", type(e).__name__,
                      " ".join(str(e).split())[:200])

    def _reload_apply(self, new) -> None:
        from .config import SCHEMA, needs_restart
        get = lambda c, k: c[k.split(".")[0]][k.split(".")[1]]
        changed = [k for k in SCHEMA if get(new, k) != get(self.cfg, k)]
        now = [k for k in changed if not needs_restart(k)]
        later = [k for k in changed if needs_restart(k)]
        for k in now:
            sec, key = k.split(".")
            self.cfg[sec][key] = new[sec][key]
        self.pipe.reconfigure(self.cfg, now)
        for sk in getattr(self, "sinks", []):
            sk.max_buffer = self.cfg["output"]["client_buffer_bytes"]
        self.worker.timeout_s = self.cfg["calibration"]["timeout_s"]
        logging.getLogger().setLevel(self.cfg["log"]["level"].upper())
        says = lambda ks: ", ".join(f"{k} ({get(self.cfg, k)} -> {get(new, k)})" if k in later else
                                    f"{k} = {get(new, k)}" for k in ks)
        log.info("configuration reloaded from %s: %s%s", self.config_path or "defaults",
                 f"applied {says(now)}" if now else "nothing changed that a reload applies",
                 f"; needs a restart (systemctl restart imucald): {says(later)}" if later else "")
        log.debug("reload: log level %s in force", self.cfg["log"]["level"])

    # -- persistence -------------------------------------------------------------------------
    def _persist(self, kind: str, obj) -> None:
        self.writer.submit(kind, obj)

    def _save(self, kind: str, obj) -> None:
        """One state write (the writer's thread; OSError is retried there)."""
        sd = self.cfg["state"]["directory"]
        self._relock_state(sd)
        if kind == "poses":
            save_poses(sd, obj, board=self.board.name)
        elif kind == "thermal":
            save_poses(sd, obj, "thermal.csv", board=self.board.name)
        else:
            save_calibration(sd, obj, self.cfg["calibration"]["history"])

    def _relock_state(self, sd: str) -> None:
        """The lock of a state directory removed and made again while the daemon runs, taken
        before writing there (a cold review: the daemon wrote into the new directory without
        its lock, and a second daemon started on it).  Told by the lock file: not the one this
        daemon holds open (a directory's inode number may come back).  Another instance
        holding the new one: an OSError (EBUSY), so the writer retries and reports it, and
        nothing is written."""
        if not os.path.isdir(sd):
            return                      # gone: the save fails and is retried
        held = getattr(self, "_state_lock_fd", None)
        try:
            st = os.stat(os.path.join(sd, LOCK_FILE))
            same = held is not None and os.path.samestat(st, os.fstat(held))
        except OSError:
            same = False
        if same:
            return
        try:
            self._lock(sd, "state.directory")
        except AlreadyRunning as e:
            raise OSError(errno.EBUSY, str(e)) from None
        except CannotCreate as e:
            raise OSError(errno.EIO, str(e)) from None
        log.warning("state.directory %s was made anew while running: its lock taken again", sd)
        if held is not None:            # the removed directory's lock: else one fd more each time
            self._lock_fds.remove(held)
            os.close(held)
        self._state_lock_fd = self._lock_fds[-1]

    def _on_stop(self, *_):
        self.stop = True

    def _on_hup(self, *_):
        self.reload = True

    def _shutdown(self) -> None:
        """Every exit path: sockets removed, worker stopped, state saved (or said why not)."""
        sd = self.cfg["state"]["directory"]
        for s in getattr(self, "sinks", []):
            s.close()
        if hasattr(self, "control"):
            self.control.close()
        if hasattr(self, "worker"):
            self.worker.shutdown(wait=True)
        if hasattr(self, "writer"):
            final = {}
            if hasattr(self, "pipe"):               # synchronous: nothing is lost
                final["poses"] = self.pipe.acc.pose_set()
                if len(self.pipe.thermal_log):
                    final["thermal"] = self.pipe.thermal_log.pose_set()
                if self.pipe.applied.id:
                    final["calibration"] = self.pipe.applied
            failed = self.writer.close(final)
            if failed:
                log.error("stopped; the %s could not be saved in %s (see above)", " and ".join(failed), sd)
            else:
                log.info("stopped; state saved in %s", sd)
        for fd in getattr(self, "_lock_fds", []):
            os.close(fd)


def _fp_text(fp: Dict[str, Any]) -> str:
    """One line: bus, then each chip with its address and trim."""
    parts = [fp.get("bus", "?")]
    for name, c in fp.get("chips", {}).items():
        parts.append(name + " " + " ".join(f"{k}={v}" for k, v in c.items()))
    return "; ".join(parts)


def _pose_json(ps, i: int) -> Dict[str, Any]:
    """One pose for the control socket; an unknown temperature is omitted (gpsd habit)."""
    d: Dict[str, Any] = {"acc_g": ps.acc[i].round(6).tolist(), "n": int(ps.n[i])}
    if ps.temp is not None and math.isfinite(ps.temp[i]):
        d["temp_c"] = round(float(ps.temp[i]), 2)
    d.update(t0=round(float(ps.t0[i]), 3), t1=round(float(ps.t1[i]), 3))
    return d
