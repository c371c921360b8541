"""The pipeline's processes keep freed memory for reuse (models/memory.py): glibc and polars' jemalloc take the
settings, and a process that builds and frees the same arrays again then pays far fewer page faults."""

import os
import resource
import subprocess
import sys

import pytest

from models.memory import POLARS_ALLOCATOR_CONF, POLARS_ALLOCATOR_ENV, keep_freed_memory

# the subprocesses' environment without this process's own allocator setting (tests/conftest.py makes it)
ENV_WITHOUT_SETTING = {k: v for k, v in os.environ.items() if k != POLARS_ALLOCATOR_ENV}

CHURN = """
import resource, sys
import numpy as np
from models.memory import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
for _ in range(3):  # warm up, as a step's later files do
    arrays = [np.ones(n) for n in (600_000, 130_000, 400_000, 70_000)]
    del arrays
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    arrays = [np.ones(n) for n in (600_000, 130_000, 400_000, 70_000)]
    del arrays
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_freed_memory_is_reused_instead_of_faulted_in_again():
    faults = {
        mode: int(subprocess.run([sys.executable, "-c", CHURN, mode], capture_output=True, text=True, check=True).stdout)
        for mode in ("default", "keep")
    }
    # ~2,360 pages of arrays per round, 20 rounds: by default most of them fault in again every round
    assert faults["keep"] * 10 < faults["default"], faults


def test_keep_freed_memory_says_whether_it_took_effect():
    assert keep_freed_memory() is sys.platform.startswith("linux")


POLARS_CHURN = """
import resource, sys, time
from models.memory import keep_freed_memory
if sys.argv[1] == "keep":
    keep_freed_memory()  # before polars loads, as pipelines/__init__.py does
import numpy as np
import polars as pl
values = pl.Series(np.arange(500_000, dtype=np.float64))
rows = pl.Series(np.arange(500_000, dtype=np.int64))
parts = [values.gather(rows) * 2.0 for _ in range(4)]  # warm up
del parts
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(4):  # a step run again after a pause, as the next file or run comes
    time.sleep(0.6)
    parts = [values.gather(rows) * 2.0 for _ in range(4)]
    del parts
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def test_polars_freed_memory_is_reused_after_a_pause():
    """polars tells its jemalloc to hand freed pages back within 0.5-1 s: by default each round after a pause faults
    its thousands of pages in again; with the setting, made before polars loads, they stay for reuse."""
    faults = {
        mode: int(subprocess.run([sys.executable, "-c", POLARS_CHURN, mode], capture_output=True, text=True, check=True, env=ENV_WITHOUT_SETTING).stdout)
        for mode in ("default", "keep")
    }
    assert faults["keep"] * 10 < faults["default"], faults


def test_the_pipeline_sets_polars_allocator_before_polars_loads():
    """Loading the code location (as Dagster's processes do) sets the option before polars reads it: polars, when it
    loads, puts its own options before ours (the later ones win), which it can only do if ours were there already."""
    code = f"import os, pipelines.definitions; print(os.environ['{POLARS_ALLOCATOR_ENV}'])"
    conf = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=ENV_WITHOUT_SETTING).stdout.strip()
    assert conf.endswith("," + POLARS_ALLOCATOR_CONF), conf
