"""Keep freed memory in the process for reuse instead of handing it back to the OS on every free (glibc's malloc).

numpy and numba allocate through glibc: by default each array above its (adaptive) threshold is a fresh `mmap`, and
freed memory above 2x that threshold is returned; each array's pages are then zeroed by the kernel on first touch. A
step that builds a few dozen arrays of 0.5-5 MB per file (the flight ingest) pays that every time: on the bundled
file ~7,700 page faults per raw -> phases chain, ~9 ms of system time in cleaning alone. With allocations below
256 MB served from the heap and up to 512 MB of free heap kept, faults fall to ~4,800 (the rest are polars' own
allocator) and the chain's median from 67 to 60 ms; the peak RSS did not move (575 -> 580 MB; measured 2026-11-29,
README's benchmarks). torch uses its own pools.

polars allocates through its own jemalloc, which it tells to hand freed pages back to the OS within 0.5-1 s
(`dirty_decay_ms:500,muzzy_decay_ms:1000`, set by polars/__init__.py), so a step run again faults them in again:
1,500-3,000 faults per chain in cleaning alone, 5-10 ms of a 15-20 ms step. polars appends the options found in
`_RJEM_MALLOC_CONF` to its own when it loads (pola-rs/polars#18088, the later option wins): set here unless polars is
loaded already, so call this before anything imports polars (pipelines/__init__.py, tests/conftest.py). Child
processes inherit them; a value the user set is kept. The pages stay with the process until it ends: `make demo`
runs every group in one process, whose peak then holds through the later groups.
"""

import ctypes
import ctypes.util
import os
import sys

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (glibc malloc.h)
MMAP_THRESHOLD_BYTES = 256 << 20  # fixed: glibc otherwise adapts it, and with it the trim threshold
TRIM_THRESHOLD_BYTES = 512 << 20
POLARS_ALLOCATOR_ENV = "_RJEM_MALLOC_CONF"
POLARS_ALLOCATOR_CONF = "dirty_decay_ms:-1,muzzy_decay_ms:-1"  # freed pages stay for reuse, never handed back


def keep_freed_memory() -> bool:
    """Set glibc's thresholds for this process (once is enough; the pipeline's processes call it when they import
    `pipelines`), and polars' allocator's where polars is not loaded yet. True where glibc took the setting;
    elsewhere (not Linux or not glibc, e.g. musl) glibc's part changes nothing."""
    if "polars" not in sys.modules:
        os.environ.setdefault(POLARS_ALLOCATOR_ENV, POLARS_ALLOCATOR_CONF)
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
