"""``piezo-ff diagnose`` keeps freed memory for its next large array: a second 200 MB array after the first is freed
faults (almost) no new pages in, where glibc's default maps and faults every such block afresh."""
import subprocess
import sys

import pytest

PROBE = r"""
import resource, sys
import numpy as np
from piezo_ff_ros.cli.diagnose import keep_freed_memory_for_reuse
applied = keep_freed_memory_for_reuse() if sys.argv[1] == "on" else False
a = np.ones(25_000_000); del a                      # 200 MB, touched, freed
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
b = np.ones(25_000_000); del b
print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(mode):
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True).stdout
    applied, faults = out.split()
    return applied == "True", int(faults)


def test_a_second_large_array_reuses_the_pages_of_the_first():
    applied, faults_on = _faults("on")
    if not applied:
        pytest.skip("not glibc: the allocator is left as it is")
    _, faults_off = _faults("off")
    # the default maps the block again and faults it in: at least one fault per 2 MB (transparent huge pages)
    assert faults_off >= 200e6 / (2 << 20) / 2
    assert faults_on < 0.1 * faults_off      # kept: its pages are reused
