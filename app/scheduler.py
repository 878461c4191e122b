"""A per-session job scheduler: jobs never overlap, and a burst ends on the last request.

Each dashboard session owns one :class:`CoalescingScheduler`. A control change submits a
job under a *slot* name (``"recompute"``, ``"time"``). While a job runs, newer submissions
only replace the waiting job of their slot (latest wins), so a burst of slider moves costs
at most one job in flight plus one for the final value, and the screen always ends showing
the last value. Slots drain in submission-priority order (``slots`` given at construction),
so a pending recompute runs before a pending time step.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

log = logging.getLogger(__name__)


class CoalescingScheduler:
    """Run submitted jobs one at a time on a worker thread, latest submission per slot wins.

    Parameters
    ----------
    slots : names of the job slots, in the order their pending jobs are run.
    on_error : called with the exception when a job raises (the worker keeps going).
    """

    def __init__(self, slots: Sequence[str] = ("recompute", "time"),
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        self._slots = tuple(slots)
        self._pending: dict[str, Callable[[], None]] = {}
        self._lock = threading.Lock()
        self._busy = False
        self._closed = False
        self._idle = threading.Event()
        self._idle.set()
        self._on_error = on_error
        self.n_submitted = 0
        self.n_run = 0
        self.n_running_max = 0  # concurrency witness for tests: must stay 1
        self._n_running = 0

    def submit(self, slot: str, job: Callable[[], None]) -> None:
        """Queue ``job`` in ``slot``, replacing a job of that slot not yet started."""
        if slot not in self._slots:
            raise ValueError(f"slot must be one of {self._slots}; got {slot!r}")
        with self._lock:
            if self._closed:
                return
            self.n_submitted += 1
            self._pending[slot] = job
            if self._busy:
                return
            self._busy = True
            self._idle.clear()
        threading.Thread(target=self._drain, name="raim-session-worker", daemon=True).start()

    def _next(self) -> Callable[[], None] | None:
        with self._lock:
            for slot in self._slots:
                job = self._pending.pop(slot, None)
                if job is not None:
                    return job
            self._busy = False
            self._idle.set()
            return None

    def _drain(self) -> None:
        while (job := self._next()) is not None:
            self._n_running += 1
            self.n_running_max = max(self.n_running_max, self._n_running)
            try:
                job()
            except Exception as exc:  # a failed job must not kill the session's worker
                log.exception("dashboard job failed")
                if self._on_error is not None:
                    self._on_error(exc)
            finally:
                self._n_running -= 1
                self.n_run += 1

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until no job is running or pending; False on timeout."""
        return self._idle.wait(timeout_s)

    def close(self) -> None:
        """Drop pending jobs and refuse new ones (the running job finishes)."""
        with self._lock:
            self._closed = True
            self._pending.clear()
