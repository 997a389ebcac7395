"""Long computations of the dashboard's sessions: the worker threads, cancelling, the event-loop
hand-over, and the server's cache of files already read and adjusted.

A served session runs its long computations (reading and adjusting a file, excluding, snooping,
robust reweighting, variance components) on :data:`TASKS`, off the server's event loop; its
:class:`Jobs` holds what they share with the session: the cancel flag, the call that schedules a
function on the session's event loop (``loop_call``, set by the app) and whether the session has
ended (``closed``). Scripts and tests compute in place (no loop, no worker).
"""

from __future__ import annotations

import logging
import os
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from ..threads import limit_worker_threads

def _worker_start() -> None:
    """Each worker thread's compiled kernels on one thread (:func:`baarda.threads.limit_worker_threads`;
    the BLAS limit is the process's): four sessions adjusting at once use four threads, not
    four times numba's default of one per core."""
    try:
        limit_worker_threads()
    except Exception:  # noqa: BLE001 - a bad BAARDA_BLAS_THREADS is reported by the command line
        _LOG.exception("could not limit the worker thread's threads")


#: Long computations (reading and adjusting a file, snooping, robust reweighting, variance
#: components, criterion fits) of every session run on these threads, off the server's event
#: loop; the numerical work releases the GIL, so other sessions keep answering.
TASKS = ThreadPoolExecutor(max_workers=4, thread_name_prefix="baarda-task", initializer=_worker_start)


_LOG = logging.getLogger("baarda.dashboard")


def next_tick(doc, fn) -> None:
    """Run ``fn()`` on the next tick of ``doc``'s event loop, where Bokeh holds its lock.

    An exception in ``fn`` is logged, not raised to Bokeh: Bokeh runs the callback inside its
    ``patch_curdoc``, which has no ``finally``, so a callback that raised would leave ``doc`` as
    ``curdoc()`` of every thread of the server for good (and, once the session ends, a destroyed
    document that every later render fails on).
    """
    def run():
        try:
            fn()
        except Exception:
            _LOG.exception("a callback of the session's page failed")
    doc.add_next_tick_callback(run)


class Cancelled(Exception):
    """Raised inside a background computation whose session asked to stop it."""


def lower_priority() -> None:
    """Lower the scheduling priority of this worker thread (Linux: nice per thread), so that
    the event loop thread answers clicks first when the CPUs are busy."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
    except (AttributeError, OSError):
        pass


def on_task_thread() -> bool:
    """True on a worker thread of :data:`TASKS`."""
    return threading.current_thread().name.startswith("baarda-task")


def on_worker_thread() -> bool:
    """True on any of baarda's worker threads (:data:`TASKS`, the app's builder)."""
    return threading.current_thread().name.startswith("baarda-")


class Jobs:
    """The background computations of one session (see the module docstring).

    ``loop_call``: schedules a callable on the session's event loop (set by the served app;
    None in scripts and tests, where everything runs in place). ``closed``: the session has
    ended (set by the app); a worker waiting for the loop then stops (:class:`Cancelled`).
    """

    def __init__(self):
        self.cancel_event = threading.Event()
        self.loop_call = None
        self.closed = False

    def reset(self) -> None:
        """A fresh cancel flag, for the next computation."""
        self.cancel_event = threading.Event()

    def start(self, run):
        """Run ``run()`` on a worker thread at a lower priority; its Future."""
        def task():
            lower_priority()
            return run()
        return TASKS.submit(task)

    def cancel(self) -> None:
        """Ask the running computation to stop (:meth:`check` raises on its thread)."""
        self.cancel_event.set()

    def cancelled(self) -> bool:
        """True on a worker thread whose session cancelled its computation."""
        return self.cancel_event.is_set() and on_task_thread()

    def check(self) -> None:
        """Raise :class:`Cancelled` in a background computation whose session cancelled it."""
        if self.cancelled():
            raise Cancelled()

    def on_loop(self, fn):
        """``fn()`` where the session's document may be changed, and its result: on the
        server's event loop when called from a worker thread of a served session (HoloViews
        and Bokeh objects are not thread-safe; the worker waits), here otherwise."""
        call = self.loop_call
        if call is None or not on_worker_thread():
            return fn()
        done, out = threading.Event(), {}

        def run():
            try:
                out["value"] = fn()
            except BaseException as err:  # noqa: BLE001 - handed back to the worker
                out["error"] = err
            finally:
                done.set()
        call(run)
        while not done.wait(1.0):
            if self.closed:
                raise Cancelled()
        if "error" in out:
            raise out["error"]
        return out.get("value")


#: Files already read and adjusted, shared by the sessions of a server: key (resolved path,
#: mtime, size, α0, β0, B-method) → (problem, adjustment, kept, index, frames). A second
#: session opens the file without reading or adjusting it again. Bounded (oldest dropped).
_LOADED: dict = {}
_LOADED_LOCKS: dict = {}
_LOADED_GUARD = threading.Lock()
LOADED_MAX = 8


def file_key(path, options, inputs=None) -> tuple | None:
    """The cache key of a file read with the core's ``options`` and the reader's companion
    files ``inputs`` (``{"control"|"gnss"|"imu": a path or the reader's options}``, each
    named by its options and its file's path, modification time and size); None if a file
    cannot be stat'ed."""
    try:
        st = os.stat(path)
        extra = []
        for name, value in sorted((inputs or {}).items()):
            if value is None:
                continue
            where = getattr(value, "path", value)
            sc = os.stat(where)
            extra.append((name, repr(value), str(Path(where).resolve()), sc.st_mtime_ns, sc.st_size))
        return (str(Path(path).resolve()), st.st_mtime_ns, st.st_size,
                options.alpha0, options.beta0, options.b_method, *extra)
    except OSError:
        return None


def file_lock(key) -> threading.Lock:
    """The lock held while the file of ``key`` is read and adjusted (other sessions wait)."""
    with _LOADED_GUARD:
        return _LOADED_LOCKS.setdefault(key, threading.Lock())


def cached(key):
    """The cached (problem, adjustment, kept, index, frames) of ``key``, or None."""
    return _LOADED.get(key) if key is not None else None


def store(key, hit) -> None:
    """Keep ``hit`` for ``key``, dropping the oldest entries beyond :data:`LOADED_MAX`."""
    with _LOADED_GUARD:
        while len(_LOADED) >= LOADED_MAX:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = hit


#: What every session would derive alike from one shared object (the cached adjustment, its
#: problem): owner → {key: [lock, value, done]}. Kept while the owner lives (weak keys), at most
#: :data:`SHARED_MAX` keys per owner (oldest dropped).
_SHARED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_SHARED_GUARD = threading.Lock()
SHARED_MAX = 16


def shared(owner, key, compute):
    """``compute()`` for ``(owner, key)``, computed once for all the sessions of a server.

    Sessions opened on a cached file share its problem and adjustment objects; what they derive
    from them alike (the suspects of a test policy, the block's footprints) is computed by the
    first session that needs it while the others wait for it (twenty sessions opened at once
    compute it once, not twenty times). ``key`` names the product and everything besides
    ``owner`` it depends on. The value is shared: callers must not change it. A ``compute`` that
    raises leaves nothing behind (the next caller computes again)."""
    with _SHARED_GUARD:
        slots = _SHARED.setdefault(owner, {})
        slot = slots.get(key)
        if slot is None:
            while len(slots) >= SHARED_MAX:
                slots.pop(next(iter(slots)))
            slot = slots[key] = [threading.Lock(), None, False]
    with slot[0]:
        if not slot[2]:
            slot[1] = compute()
            slot[2] = True
        return slot[1]


def clear_cache() -> None:
    """Forget every cached file (tests; a server frees the memory)."""
    with _LOADED_GUARD:
        _LOADED.clear()
        _LOADED_LOCKS.clear()
    with _SHARED_GUARD:
        _SHARED.clear()
