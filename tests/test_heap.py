"""release_free_heap gives freed heap space back to the OS (the batched learner calls it once per epoch: without it
a 4-run study grew to 22 GB of free-but-kept heap and was killed)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from surrol_data.algos.heap import _malloc_trim, release_free_heap


def _anon_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no RssAnon in /proc/self/status")


@pytest.mark.skipif(not sys.platform.startswith("linux") or _malloc_trim() is None, reason="needs glibc's malloc_trim")
def test_freed_heap_between_live_blocks_goes_back_to_the_os():
    # 64 KB blocks (below glibc's mmap threshold: they come from the heap), each followed by a 1 KB block that
    # stays alive (above pymalloc's 512 B: also from the heap), so freeing the big ones cannot shrink the heap's top
    big, live = [], []
    for _ in range(4000):
        big.append(bytearray(64 * 1024))
        live.append(bytearray(1024))
    del big
    freed_but_kept = _anon_mb()
    assert release_free_heap()
    after = _anon_mb()
    assert freed_but_kept - after > 150, (freed_but_kept, after)   # of the 250 MB freed
    assert len(live) == 4000
