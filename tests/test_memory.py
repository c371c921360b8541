"""The pipeline's processes keep freed memory for reuse (models/memory.py): glibc takes the setting, and a process that
builds and frees the same arrays again then pays far fewer page faults."""

import resource
import subprocess
import sys

import pytest

from models.memory import keep_freed_memory

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
