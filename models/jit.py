"""numba's njit with its on-disk cache where it can have one: the one decorator of the compiled kernels
(models/aviation/kernels.py, models/dcb/kernels.py, models/urban/kernels.py)."""

from numba import njit


def jit(fn=None, **options):
    """njit with numba's on-disk cache where numba finds a writable cache directory, without it elsewhere (numba
    would refuse to define a cached function at all). A kernel's cache is invalidated by a change of the kernel's own
    file only, not of this one."""
    if fn is None:
        return lambda f: jit(f, **options)
    try:
        return njit(cache=True, **options)(fn)
    except RuntimeError as e:  # "cannot cache function ...: no locator available for file ..."
        if "no locator" not in str(e):
            raise
        return njit(**options)(fn)
