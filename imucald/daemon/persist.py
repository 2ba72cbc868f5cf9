"""State writes off the sampler's thread, retried while the state directory refuses them.

The newest poses and the newest calibration are kept in memory until they are on
disk: a read-only or full state directory costs nothing but a log line (one per
change of error) and a ``state`` entry in ``status``; once the directory takes
writes again, the calibration in force is written (intermediate ones are not:
only the newest matters to the next start).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Dict, List, Optional

__all__ = ["StateWriter", "RETRY_S"]

log = logging.getLogger("imucald")

#: seconds between attempts after a failure (the last one repeats)
RETRY_S = (1.0, 2.0, 5.0, 10.0, 30.0)


class StateWriter:
    """``save(kind, obj)`` writes one object (kinds: "calibration", "poses", "thermal"); ``where``
    names the directory for messages."""

    def __init__(self, save: Callable[[str, Any], None], where: str, retry_s=RETRY_S):
        self.save, self.where, self.retry_s = save, where, tuple(retry_s)
        self._cond = threading.Condition()
        self._pending: Dict[str, Any] = {}
        self._writing: Optional[str] = None      # the kind being written: unsaved until it is
        self._stop = False
        self.error: Optional[str] = None         #: the last failure, None once writes succeed
        self.failing_since: Optional[float] = None
        self.failures = 0                        #: failed attempts in a row
        self.written = 0
        self._thread = threading.Thread(target=self._run, name="imucald-state", daemon=True)
        self._thread.start()

    def submit(self, kind: str, obj: Any) -> None:
        with self._cond:
            self._pending[kind] = obj            # a newer object replaces one not yet written
            self._cond.notify()

    def status(self) -> Dict[str, Any]:
        with self._cond:
            unsaved = set(self._pending) | ({self._writing} if self._writing else set())
            d: Dict[str, Any] = {"ok": self.error is None, "unsaved": sorted(unsaved),
                                 "written": self.written}
            if self.error is not None:
                d.update(error=self.error, failing_s=round(time.monotonic() - self.failing_since, 1),
                         attempts=self.failures)
            return d

    def _take(self):
        for kind in ("calibration", "poses"):
            if kind in self._pending:
                return kind, self._pending.pop(kind)
        kind = next(iter(self._pending))
        return kind, self._pending.pop(kind)

    def _attempt(self, kind: str, obj: Any) -> bool:
        try:
            self.save(kind, obj)
        except OSError as e:
            msg = f"could not save the {kind} in {self.where}: {e.strerror or e}"
            with self._cond:
                self._pending.setdefault(kind, obj)      # unless a newer one came meanwhile
                if self.error is None:
                    self.failing_since = time.monotonic()
                self.failures += 1
                changed, self.error = msg != self.error, msg
            if changed:
                log.error("%s; kept in memory, retrying (imucald status shows it)", msg)
            return False
        with self._cond:
            self.written += 1
            if self.error is not None:
                log.warning("state saved in %s again after %d failed attempts", self.where, self.failures)
            self.error, self.failing_since, self.failures = None, None, 0
        return True

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                kind, obj = self._take()
                self._writing = kind
            ok = self._attempt(kind, obj)
            with self._cond:
                self._writing = None
            if not ok:
                delay = self.retry_s[min(self.failures - 1, len(self.retry_s) - 1)]
                with self._cond:
                    self._cond.wait_for(lambda: self._stop, timeout=delay)

    def close(self, final: Optional[Dict[str, Any]] = None) -> List[str]:
        """Stop the thread, then write what is pending (and ``final``, kind -> obj) once,
        synchronously; returns the kinds that could not be written."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout=30)
        with self._cond:
            todo = dict(self._pending)
            todo.update(final or {})
            self._pending.clear()
        failed = []
        for kind in ("poses", "thermal", "calibration"):
            if kind in todo and not self._attempt(kind, todo[kind]):
                failed.append(kind)
        return failed
