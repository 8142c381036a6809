"""Freed host memory kept while scoring on a CPU (glibc): counted in page faults, not time."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import numpy as np
import pytest

from cgvqm_core import host_memory
from cgvqm_core.features import FeatureNet
from cgvqm_core.hub import random_backbone
from cgvqm_core.stream import ArraySource, patch_channel_msd

pytestmark = pytest.mark.skipif(not host_memory.available(),
                                reason="not glibc, or malloc tuned through MALLOC_* variables")

SMALL = 6 * 2**20  # float32 elements: 24 MiB, a block glibc can keep
LARGE = 12 * 2**20  # 48 MiB: always its own mapping
PAGE = resource.getpagesize()


def _pages(elements: int = SMALL) -> int:
    return elements * 4 // PAGE


# In a fresh process, so that the heap holds nothing else. numpy's plain malloc, without its
# huge-page advice: torch's 64-byte-aligned allocations ask glibc for a little more than the
# block they free, so whether the very next one fits its hole depends on where the heap
# happens to start (a scoring run reuses its holes: 6 thousand page faults against 152).
PROBE = """
import json, resource
import numpy as np
from cgvqm_core import host_memory

(np._core if hasattr(np, "_core") else np.core).multiarray._set_madvise_hugepage(False)

def faults(elements):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(elements, dtype=np.float32)
    del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

small, large = %d, %d
out = {}
with host_memory.retained():
    faults(small)  # the heap grows once
    out["inside"] = [faults(small) for _ in range(3)]
    out["large_inside"] = faults(large)
    with host_memory.retained():
        faults(small)
    out["after_inner_exit"] = faults(small)
out["after"] = [faults(small) for _ in range(3)]
with host_memory.disabled(), host_memory.retained():
    out["disabled"] = [faults(small) for _ in range(3)]
print(json.dumps(out))
"""


def test_blocks_are_reused_inside_and_returned_after():
    out = subprocess.run([sys.executable, "-c", PROBE % (SMALL, LARGE)], capture_output=True,
                         text=True, check=True, timeout=120)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert max(got["inside"]) < _pages() // 10
    # above glibc's largest threshold a block keeps its own mapping (heap fragmentation)
    assert got["large_inside"] > _pages(LARGE) // 2
    assert got["after_inner_exit"] < _pages() // 10  # the outer block still keeps memory
    # glibc's defaults are back (a fixed 128 KiB threshold) and the kept memory returned
    assert min(got["after"]) > _pages() // 2
    assert min(got["disabled"]) > _pages() // 2  # disabled() turns retained() off


def test_malloc_settings_of_the_user_are_left_alone():
    code = "from cgvqm_core import host_memory; print(host_memory.available())"
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "1048576"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == "False"


def test_cpu_scoring_keeps_memory_while_it_runs_and_restores_after(monkeypatch):
    calls = []
    real = host_memory.retained

    def spy(enabled: bool = True):
        calls.append(enabled)
        return real(enabled)

    monkeypatch.setattr("cgvqm_core.stream.retained", spy)
    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8)
    test = np.clip(ref.astype(int) + rng.integers(-9, 10, ref.shape), 0, 255).astype(np.uint8)
    net = FeatureNet(random_backbone(0), 3)
    kept = patch_channel_msd(ArraySource(ref, 30, "r"), [ArraySource(test, 30, "t")], net)
    assert calls == [True]
    assert host_memory._users == 0  # left: glibc's defaults restored
    with host_memory.disabled():  # the same numbers without it
        plain = patch_channel_msd(ArraySource(ref, 30, "r"), [ArraySource(test, 30, "t")], net)
    np.testing.assert_array_equal(kept[0].msd, plain[0].msd)
