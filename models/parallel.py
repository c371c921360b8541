"""Jobs in parallel processes: libsumo runs one simulation per process, and the small torch trainings
run on one thread each, so on a 2-core machine two processes do twice the work of one. And calls at once in
threads (`together`), for work that releases the GIL (polars, numpy, nogil numba kernels).

`ProcessPool(workers, fn)` is a callable `jobs -> results` (in order); `pool.iter(jobs)` yields them in
order as they finish, for progress logs. workers = 1 runs in this process. Workers are spawned (not
forked): a fork of a process holding a libsumo simulation or torch threads is not safe. Each job must
seed its own randomness, so results do not depend on the number of workers.
"""

import multiprocessing
import os
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor


def usable_cores() -> int:
    """Cores this process may run on (the default number of workers)."""
    return len(os.sched_getaffinity(0))


_threads: ThreadPoolExecutor | None = None


def together(*calls):
    """Run the zero-argument `calls` at once, the last in this thread, the others in a pool of one thread per usable
    core; returns their results in order (an exception of one is raised here). For pieces of one step that release
    the GIL: on the flight ingest polars' own threads leave the second core idle."""
    global _threads
    # one call needs no thread; from one of the pool's own threads, waiting on the pool could wait forever
    if len(calls) < 2 or threading.current_thread().name.startswith("together"):
        return [call() for call in calls]
    if _threads is None:
        _threads = ThreadPoolExecutor(usable_cores(), thread_name_prefix="together")
    futures = [_threads.submit(call) for call in calls[:-1]]
    last = calls[-1]()
    return [f.result() for f in futures] + [last]


def _init_worker():
    import torch

    torch.set_num_threads(1)


class ProcessPool:
    def __init__(self, workers: int, fn):
        self.workers, self.fn = max(int(workers), 1), fn
        self._pool = None

    def __enter__(self):
        if self.workers > 1:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker)
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def iter(self, jobs: list) -> Iterator:
        return (self.fn(j) for j in jobs) if self._pool is None else self._pool.map(self.fn, jobs)

    def __call__(self, jobs: list) -> list:
        return list(self.iter(jobs))
