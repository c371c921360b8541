"""Keep freed memory in the process for reuse instead of handing it back to the OS on every free (glibc's malloc).

numpy and numba allocate through glibc: by default each array above its (adaptive) threshold is a fresh `mmap`, and
freed memory above 2x that threshold is returned; each array's pages are then zeroed by the kernel on first touch. A
step that builds a few dozen arrays of 0.5-5 MB per file (the flight ingest) pays that every time: on the bundled
file ~7,700 page faults per raw -> phases chain, ~9 ms of system time in cleaning alone. With allocations below
256 MB served from the heap and up to 512 MB of free heap kept, faults fall to ~4,800 (the rest are polars' own
allocator) and the chain's median from 67 to 60 ms; the peak RSS did not move (575 -> 580 MB; measured 2026-11-29,
README's benchmarks). polars uses jemalloc and torch its own pools; this changes only what goes through glibc.
"""

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (glibc malloc.h)
MMAP_THRESHOLD_BYTES = 256 << 20  # fixed: glibc otherwise adapts it, and with it the trim threshold
TRIM_THRESHOLD_BYTES = 512 << 20


def keep_freed_memory() -> bool:
    """Set glibc's thresholds for this process (once is enough; the pipeline's processes call it when they load the
    code location). True where it took effect; elsewhere (not Linux or not glibc, e.g. musl) nothing changes."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
