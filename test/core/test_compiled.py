"""core/compiled.py's own helpers (the compiled algorithms' tests are in their stages' files)."""

from __future__ import annotations

import resource
import sys
from collections.abc import Callable

import pytest

from turning_force.core.compiled import in_one_chunk

DIVES, DEPTH = 2000, 600


def _dive(n: int) -> int:
    return _dive(n - 1) + 1 if n else 0


def _churn() -> None:
    for _ in range(DIVES):
        _dive(DEPTH)


def _page_faults(call: Callable[[], object]) -> int:
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    call()
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before


def test_a_call_in_one_chunk_maps_no_chunk_of_the_frame_stack_as_it_recurses():
    # CPython 3.11 and 3.12 map a 16 KiB chunk of the frame stack each time a call crosses
    # into it and unmap it when the call returns (gh-142183): 2,000 dives 600 frames deep
    # (about 50 kB of frames, three chunks) fault in the pages of each new chunk every time,
    # 13 per dive here. Under in_one_chunk every frame of them is in the one chunk mapped for
    # it (1 MiB, 256 pages), whose pages fault in once: 146 here, and a few more of whatever
    # else the process does meanwhile.
    assert in_one_chunk(lambda: _dive(DEPTH)) == DEPTH
    roomy = _page_faults(lambda: in_one_chunk(_churn))
    assert roomy < 256 + 40
    if sys.version_info[:2] in ((3, 11), (3, 12)):   # the thrash it avoids, where it is
        assert _page_faults(_churn) > 3 * DIVES


def test_in_one_chunk_raises_what_the_call_raises():
    def fail() -> None:
        raise ValueError('from inside')

    with pytest.raises(ValueError, match='from inside'):
        in_one_chunk(fail)
