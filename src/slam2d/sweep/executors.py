"""Where runs execute: a pool of local worker processes, or a Dask distributed cluster.

Both give the sweep engine the same three calls: :meth:`submit` a task under
a key, :meth:`next_done` for the next finished one, :meth:`close`.
``next_done`` returns ``(key, kind, value)`` where ``kind`` is

* ``"ok"``: the function returned ``value``;
* ``"error"``: the function raised (``value`` is the error line and traceback);
* ``"lost"``: the worker died while it held the task (``value`` says how);
  the engine retries such a task once.

The local pool keeps its worker processes (imports and numba's compiled code
are loaded once per worker, not once per run) and watches each one: a worker
that dies is replaced and only the task it held is lost.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from slam2d.errors import InputError

__all__ = ["LocalPool", "DaskExecutor", "make_executor"]


def _die_with_parent() -> None:
    """Linux: have the kernel send SIGTERM when the parent dies, even by SIGKILL, mid-task (best effort)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _worker_loop(conn: Any, parent_end: Any, parent_pid: int) -> None:
    """Body of a pool worker: run tasks from the pipe until told to stop, or until the parent is gone.

    A forked worker inherits the parent's end of its own pipe; held open here, it would keep the pipe from
    ever reporting the parent's death, and a killed sweep left its workers blocked forever (parent pid 1).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    if parent_end is not None:
        parent_end.close()
    _die_with_parent()
    while True:
        try:
            while not conn.poll(1.0):
                if os.getppid() != parent_pid:  # orphaned (where the kernel's signal is not available)
                    os._exit(0)
            message = conn.recv()
        except (EOFError, OSError):
            break
        if message is None:
            break
        key, fn, arg = message
        try:
            reply = (key, "ok", fn(arg))
        except Exception as exc:
            reply = (key, "error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}")
        conn.send(reply)
    os._exit(0)


@dataclass
class _Worker:
    proc: Any
    conn: Any
    key: str | None = None


class LocalPool:
    """``workers`` local processes, each running one task at a time."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise InputError(f"{workers} must be at least 1", field="--workers")
        methods = multiprocessing.get_all_start_methods()
        # fork: a worker starts at once with everything imported (and methods a test registered)
        self._ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
        self.capacity = workers
        self._workers: list[_Worker] = []
        self._waiting: deque[tuple[str, Callable[[Any], Any], Any]] = deque()

    def describe(self) -> str:
        return f"local pool of {self.capacity} worker process(es)"

    def pids(self) -> list[int]:
        return [w.proc.pid for w in self._workers]

    def busy_pids(self) -> dict[str, int]:
        """Key of each running task -> the pid of the worker running it."""
        return {w.key: w.proc.pid for w in self._workers if w.key is not None}

    def _start_worker(self) -> _Worker:
        if not self._workers and self._ctx.get_start_method() == "fork":
            from slam2d.sweep.execute import warm_imports

            warm_imports()  # once, in the parent: every forked worker starts with it imported
        parent, child = self._ctx.Pipe()
        forked = self._ctx.get_start_method() == "fork"
        proc = self._ctx.Process(target=_worker_loop, args=(child, parent if forked else None, os.getpid()),
                                 name="slam2d-sweep-worker", daemon=True)
        proc.start()
        child.close()
        w = _Worker(proc, parent)
        self._workers.append(w)
        return w

    def submit(self, key: str, fn: Callable[[Any], Any], arg: Any) -> None:
        self._waiting.append((key, fn, arg))

    def _dispatch(self) -> None:
        while self._waiting:
            idle = next((w for w in self._workers if w.key is None), None)
            if idle is None:
                if len(self._workers) >= self.capacity:
                    return
                idle = self._start_worker()
            key, fn, arg = self._waiting.popleft()
            idle.key = key
            idle.conn.send((key, fn, arg))

    def pending(self) -> int:
        return len(self._waiting) + sum(w.key is not None for w in self._workers)

    def next_done(self) -> tuple[str, str, Any]:
        from multiprocessing.connection import wait

        while True:
            self._dispatch()
            busy = [w for w in self._workers if w.key is not None]
            if not busy:
                raise RuntimeError("next_done() with nothing submitted")
            wait([w.conn for w in busy] + [w.proc.sentinel for w in busy])
            for w in busy:
                try:
                    has_reply = w.conn.poll()
                    if has_reply:
                        key, kind, value = w.conn.recv()
                        w.key = None
                        return key, kind, value
                except (EOFError, OSError):
                    pass  # the pipe broke: the worker is gone, handled below
                if not w.proc.is_alive():
                    w.proc.join()
                    key, code = w.key, w.proc.exitcode
                    w.conn.close()
                    self._workers.remove(w)
                    how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit status {code}"
                    return key, "lost", f"the worker process (pid {w.proc.pid}) died: {how}"

    def close(self) -> None:
        for w in self._workers:
            try:
                w.conn.send(None)
            except OSError:
                pass
        for w in self._workers:
            w.proc.join(timeout=5)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join()
            w.conn.close()
        self._workers.clear()


class DaskExecutor:
    """Tasks go to the workers of a running ``dask.distributed`` scheduler.

    Workers must be able to import slam2d and see the sweep's output folder and
    data at the same paths (a shared file system). ``workers``: wait until that
    many workers have joined before submitting.
    """

    def __init__(self, address: str, workers: int | None = None, timeout: float = 20.0) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise InputError("running on a Dask cluster needs dask.distributed: pip install 'slam2d[sweep]'",
                             field="--scheduler") from None
        self.address = address
        try:
            self.client = Client(address, timeout=f"{timeout}s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot connect to the Dask scheduler at {address}: {exc}".splitlines()[0],
                             field="--scheduler") from None
        if workers:
            try:
                self.client.wait_for_workers(workers, timeout=timeout * 3)
            except TimeoutError:
                have = len(self.client.scheduler_info().get("workers", {}))
                self.client.close()
                raise InputError(f"only {have} of the {workers} workers asked for joined the scheduler at {address}",
                                 field="--workers") from None
        from distributed import as_completed

        self._done = as_completed()
        self._keys: dict[str, str] = {}
        self._tries: dict[str, int] = {}
        self.capacity = max(1, sum(w.get("nthreads", 1) for w in self.client.scheduler_info()["workers"].values()))

    def describe(self) -> str:
        n = len(self.client.scheduler_info()["workers"])
        return f"Dask scheduler {self.address} with {n} worker(s), {self.capacity} thread(s)"

    def submit(self, key: str, fn: Callable[[Any], Any], arg: Any) -> None:
        n = self._tries[key] = self._tries.get(key, 0) + 1
        future = self.client.submit(fn, arg, key=f"slam2d-{key}-try{n}", pure=False)
        self._keys[future.key] = key
        self._done.add(future)

    def pending(self) -> int:
        return len(self._keys)

    def next_done(self) -> tuple[str, str, Any]:
        from distributed import KilledWorker

        future = next(self._done)
        key = self._keys.pop(future.key)
        try:
            if future.status == "finished":
                return key, "ok", future.result()
            if future.status == "cancelled":
                return key, "lost", "the task was cancelled by the scheduler (its worker left)"
            exc = future.exception()
            if isinstance(exc, KilledWorker):
                return key, "lost", f"the Dask worker running it died ({exc})".splitlines()[0]
            return key, "error", f"{type(exc).__name__}: {exc}"
        finally:
            future.release()

    def close(self) -> None:
        self.client.close()


def make_executor(scheduler: str | None, workers: int | None) -> LocalPool | DaskExecutor:
    if scheduler:
        return DaskExecutor(scheduler, workers)
    return LocalPool(workers if workers is not None else (os.cpu_count() or 1))
