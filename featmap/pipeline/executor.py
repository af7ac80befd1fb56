"""Where per-item work runs: in this process, on a pool of local processes, or on a Dask cluster.

The pipeline and sweeps take an executor instead of starting pools themselves, so the same code runs in
a notebook, on two local processes, on a Dask client, or inside a batch task (where starting a pool is
not allowed). ``imap`` keeps at most ``window`` items in flight, so a long input is never materialised
in memory, and yields results in the input's order. ``share(obj)`` returns what to put into the items
instead of a large object every item uses (the object itself locally; a Dask future, sent once, on a
cluster).
"""

from __future__ import annotations

from collections import deque
from typing import Any, Callable, Iterable, Iterator, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class Executor(Protocol):
    workers: int

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]: ...

    def share(self, obj: T) -> T: ...


class SerialExecutor:
    """Runs every item in this process, one after the other."""

    workers = 1

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        return map(fn, items)

    def share(self, obj: T) -> T:
        return obj

    def close(self) -> None:
        pass

    def __enter__(self) -> "SerialExecutor":
        return self

    def __exit__(self, *exc) -> None:
        pass


def bounded_imap(submit: Callable[[T], Any], items: Iterable[T], window: int) -> Iterator:
    """Results of ``submit(item)`` futures (``.result()``, ``.cancel()``) in the items' order, with at most
    ``window`` submitted and not yet yielded; the pending ones are cancelled when the caller stops early."""
    pending: deque = deque()
    try:
        for item in items:
            pending.append(submit(item))
            if len(pending) >= window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for future in pending:
            future.cancel()


def _limit_threads() -> None:
    """Worker initializer: one BLAS/OpenMP thread per worker process (the workers are the parallelism)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


class ProcessExecutor:
    """A pool of ``workers`` local processes (spawned: Open3D and fork do not mix), started on first use.

    Use it as a context manager (or call :meth:`close`) so the processes end with it. ``fn`` and the
    items must be picklable (module-level functions, numpy arrays, frozen dataclasses).
    """

    def __init__(self, workers: int = 2, window: int | None = None):
        self.workers = max(1, int(workers))
        self.window = window or 2 * self.workers
        self._pool = None

    def _get_pool(self):
        if self._pool is None:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"), initializer=_limit_threads)
        return self._pool

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        return bounded_imap(lambda item: self._get_pool().submit(fn, item), items, self.window)

    def share(self, obj: T) -> T:
        return obj

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __enter__(self) -> "ProcessExecutor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class DaskExecutor:
    """Runs items as tasks on a Dask ``distributed.Client`` (a LocalCluster or a remote scheduler).

    ``imap`` has the contract of the other executors: at most ``window`` tasks in flight (default: two
    per worker thread of the cluster when it is created), results in the input's order, and the tasks
    still pending are cancelled when the caller stops early. A task's exception is raised by ``imap``.
    ``fn`` and the items travel by pickle to the workers, which must import featmap (the same version).
    The client is the caller's: :meth:`close` does not close it.

    Args:
        client: a connected ``distributed.Client``.
        window: tasks in flight (None: twice the cluster's worker threads).
    """

    def __init__(self, client, window: int | None = None):
        self.client = client
        self.workers = max(1, sum(client.nthreads().values()))
        self.window = window or 2 * self.workers

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        return bounded_imap(lambda item: self.client.submit(fn, item, pure=False), items, self.window)

    def share(self, obj: T) -> T:
        """A future of ``obj`` held by the cluster: put it into items instead of ``obj`` (sent once, not per task)."""
        return self.client.scatter(obj, broadcast=False, hash=False)

    def close(self) -> None:
        pass

    def __enter__(self) -> "DaskExecutor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def local_executor(workers: int) -> SerialExecutor | ProcessExecutor:
    """A serial executor for one worker, a process pool otherwise."""
    return SerialExecutor() if workers <= 1 else ProcessExecutor(workers)
