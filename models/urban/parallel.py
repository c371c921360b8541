"""Episodes in parallel processes: libsumo runs one simulation per process, so each worker is a process.

`EpisodePool(workers)` is a callable `jobs -> results` (in order). workers = 1 runs in this process.
Workers are spawned (not forked): a fork of a process holding a libsumo simulation or torch threads is
not safe.
"""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor


def _init_worker():
    import torch

    torch.set_num_threads(1)


class EpisodePool:
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

    def __call__(self, jobs: list) -> list:
        if self._pool is None:
            return [self.fn(j) for j in jobs]
        return list(self._pool.map(self.fn, jobs))
