"""The calibration worker: one short-lived process per job, supervised by the daemon.

Why a process per job (and not a pool): an idle daemon holds no worker at all
(no resident memory between calibrations, no multiprocessing resource tracker),
a worker killed by the OOM killer or hung in a fit costs that one job only, and
the next job starts from a clean interpreter.

Protocol: the daemon starts ``python -m imucald.daemon.worker FD`` with the job,
pickled as (module, function, args), on its stdin; the worker imports only that
function's module, runs it at lower priority and writes the pickled
("ok", result) or ("error", one-line message) to its stdout.  FD is the read end
of a pipe whose write end only the daemon holds: when the daemon dies (kill -9
included) the read sees end-of-file and the worker exits at once.

:class:`WorkerRunner` is an executor (``submit`` returns a Future) whose jobs are
supervised by a thread each: a per-job timeout (the process is killed), a death
reported as one line (signal named), never an exception in the sampler.
"""
from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading
from concurrent.futures import Executor, Future

__all__ = ["WorkerRunner", "WorkerDied", "WorkerTimeout", "main", "without_openssl"]


def without_openssl() -> bool:
    """Keep OpenSSL's libcrypto out of this process, before anything imports hashlib:
    numpy.random loads it (through secrets and hmac) though nothing here uses it, and it
    costs ~3.5 MB resident in the daemon and again in each worker.  hashlib then serves
    SHA-256 (the sensor fingerprint) from Python's built-in module: the same digests.
    Only where that built-in module exists (some builds leave it out); returns True if
    applied."""
    import importlib.util
    if "hashlib" in sys.modules or "_hashlib" in sys.modules:
        return False
    if not any(importlib.util.find_spec(m) for m in ("_sha256", "_sha2")):
        return False
    sys.modules["_hashlib"] = None       # import _hashlib raises ImportError: the fallback
    return True


class WorkerDied(RuntimeError):
    """The worker process ended without a result (killed, crashed)."""


class WorkerTimeout(RuntimeError):
    """The job ran past its time limit; the worker was killed."""


def _signal_name(rc: int) -> str:
    try:
        return signal.Signals(-rc).name
    except ValueError:
        return f"signal {-rc}"


class WorkerRunner(Executor):
    """Runs ``fn(*args)`` in a fresh worker process per job (``fn`` a module-level
    function), at most ``timeout_s`` each."""

    def __init__(self, timeout_s: float = 600.0, nice: int = 10):
        self.timeout_s, self.nice = float(timeout_s), nice
        self._lock = threading.Lock()
        self._procs = set()          # running worker processes
        self.started = 0             #: workers started
        self.died = 0                #: workers that ended without a result (killed, crashed)
        self.timeouts = 0            #: workers killed at the time limit
        self._closed = False

    def submit(self, fn, *args, **kwargs) -> Future:
        f: Future = Future()
        if self._closed:
            raise RuntimeError("the worker runner is shut down")
        payload = pickle.dumps((fn.__module__, fn.__qualname__, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL)
        threading.Thread(target=self._supervise, args=(f, payload), daemon=True,
                         name="imucald-worker").start()
        return f

    def _supervise(self, f: Future, payload: bytes) -> None:
        r, w = os.pipe()                 # parent-death pipe: only this process holds w
        try:
            p = subprocess.Popen([sys.executable, "-m", __name__, str(r), str(self.nice)],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, pass_fds=(r,),
                                 close_fds=True)
        except OSError as e:
            os.close(r)
            os.close(w)
            f.set_exception(WorkerDied(f"cannot start the calibration worker: {e.strerror}"))
            return
        os.close(r)
        with self._lock:
            self._procs.add(p)
            self.started += 1
        result, error = None, None
        try:
            result, error = self._outcome(p, payload)
        except BaseException as e:          # never lose the future
            error = WorkerDied(f"calibration worker: {e}")
        finally:
            os.close(w)
            with self._lock:
                self._procs.discard(p)      # gone before the future says done
        if error is not None:
            f.set_exception(error)
        else:
            f.set_result(result)

    def _outcome(self, p, payload: bytes):
        """(result, None) or (None, exception) of one worker process."""
        try:
            out, _ = p.communicate(payload, timeout=self.timeout_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate()
            with self._lock:
                self.timeouts += 1
            return None, WorkerTimeout(f"calibration took longer than {self.timeout_s:g} s "
                                       f"(calibration.timeout_s): the worker was stopped")
        if p.returncode != 0 or not out:
            with self._lock:
                self.died += 1
            how = (f"was killed ({_signal_name(p.returncode)}; the OOM killer sends SIGKILL)"
                   if p.returncode < 0 else f"exited with status {p.returncode}")
            return None, WorkerDied(f"the calibration worker {how} without a result; the "
                                    f"next calibration starts a new one")
        status, value = pickle.loads(out)
        return (value, None) if status == "ok" else (None, RuntimeError(value))

    def running(self) -> int:
        with self._lock:
            return len(self._procs)

    def pids(self):
        with self._lock:
            return [p.pid for p in self._procs]

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop: running workers are killed (a calibration in progress is abandoned)."""
        self._closed = True
        with self._lock:
            procs = list(self._procs)
        for p in procs:
            try:
                p.kill()
            except OSError:
                pass
        if wait:
            for p in procs:
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    pass


def _watch_parent(fd: int) -> None:
    try:
        while os.read(fd, 1):
            pass
    except OSError:
        pass
    os._exit(3)                      # the daemon is gone: so is its job


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    fd, nice = int(argv[0]), int(argv[1]) if len(argv) > 1 else 10
    threading.Thread(target=_watch_parent, args=(fd,), daemon=True).start()
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # Ctrl-C is the daemon's to handle
    try:
        os.nice(nice)                # on a one-core Pi the sampler keeps priority over the fit
    except OSError:
        pass
    out = sys.stdout.buffer
    without_openssl()
    try:
        mod, name, args, kwargs = pickle.loads(sys.stdin.buffer.read())
        import importlib
        fn = importlib.import_module(mod)
        for part in name.split("."):
            fn = getattr(fn, part)
        res = ("ok", fn(*args, **kwargs))
    except Exception as e:           # the job's failure, in one line for the daemon's log
        res = ("error", f"{type(e).__name__}: {' '.join(str(e).split())}")
    try:
        out.write(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
        out.flush()
    except (BrokenPipeError, ConnectionResetError):     # the daemon died meanwhile: no one to
        os._exit(3)                                     # tell, nothing to print (no traceback)
    return 0


if __name__ == "__main__":
    sys.exit(main())
