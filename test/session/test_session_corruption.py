"""Property: whatever happens to a session's MCAP file (bytes overwritten, bits flipped, the file
cut short, several at once), reading it gives a BagError or exactly the recorded data: never
another exception, never silently fewer messages.

Two files are corrupted: the committed reference session (re-recorded with a CRC-32 on every
chunk, issue 17 U7) and the same messages written through today's SessionWriter. Both carry
the CRCs, so in both the data read is exactly the reference's: a changed byte inside a chunk's
zstd data (zstd keeps no checksum of its own here) is caught by the chunk's CRC. A chunk
without a CRC is named unverifiable (test/session/test_bag_tools.py).

Deterministic (derandomized, a fixed number of examples), so that CI does not flake.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bagfaults import REFERENCE, REFERENCE_BLOCKS, mcap_of, rewrite
from turning_force.session.bag import BagError
from turning_force.session.reader import Session, read_session

EXAMPLES = 30   # per file; about 0.3 s each on this machine, unloaded

# A corruption: (kind, where as a fraction of the file, how much / which bits / what bytes)
corruption = st.one_of(
    st.tuples(st.just('overwrite'), st.floats(0.0, 1.0), st.binary(min_size=1, max_size=4096)),
    st.tuples(st.just('flip'), st.floats(0.0, 1.0), st.integers(1, 255)),
    st.tuples(st.just('truncate'), st.floats(0.0, 1.0), st.none()),
)
corruptions = st.lists(corruption, min_size=1, max_size=3)
SETTINGS = settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


def corrupt(raw: bytes, steps: list[tuple[str, float, object]]) -> tuple[bytes, list[range]]:
    """The corrupted bytes and the byte ranges the corruption changed or removed."""
    data = bytearray(raw)
    touched = []
    for kind, where, what in steps:
        offset = min(int(where * len(data)), max(len(data) - 1, 0))
        if kind == 'overwrite':
            assert isinstance(what, bytes)
            data[offset:offset + len(what)] = what
            touched.append(range(offset, offset + len(what)))
        elif kind == 'flip' and data:
            assert isinstance(what, int)
            data[offset] ^= what
            touched.append(range(offset, offset + 1))
        elif kind == 'truncate':
            touched.append(range(offset, len(raw)))
            del data[offset:]
    return bytes(data), touched


def recorded_equal(session: Session, reference: Session) -> bool:
    if len(session.blocks) != len(reference.blocks):
        return False
    fields = ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')
    for a, b in zip(session.blocks, reference.blocks, strict=True):
        if a.t0_s != b.t0_s or a.sample_period_s != b.sample_period_s:
            return False
        if not all(np.array_equal(getattr(a, f), getattr(b, f)) for f in fields):
            return False
    return all(np.array_equal(session.signals[k], v, equal_nan=True)
               for k, v in reference.signals.items())



@pytest.fixture(scope='module')
def written_today(tmp_path_factory: pytest.TempPathFactory, reference: Session) \
        -> tuple[Path, dict[str, int]]:
    bag = rewrite(REFERENCE, tmp_path_factory.mktemp('today') / 'fig8')
    assert recorded_equal(read_session(bag), reference)
    return bag, read_session(bag).message_counts


@pytest.fixture(scope='module')
def committed() -> dict[str, int]:
    """The reference's message counts."""
    return read_session(REFERENCE).message_counts


def read_corrupted(bag: Path, steps: list[tuple[str, float, object]]) \
        -> tuple[Session | None, dict[str, int], list[range]]:
    """Read a corrupted copy of ``bag``: (the session, or None for a BagError; its message
    counts; the byte ranges corrupted)."""
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / bag.name
        shutil.copytree(bag, copy)
        data, touched = corrupt(mcap_of(bag).read_bytes(), steps)
        mcap_of(copy).write_bytes(data)
        try:
            session = read_session(copy)
        except BagError:
            return None, {}, touched
        return session, session.message_counts, touched


@SETTINGS
@given(steps=corruptions)
def test_a_written_session_reads_exactly_or_not_at_all(written_today, reference, steps):
    bag, counts = written_today
    session, got, _ = read_corrupted(bag, steps)
    if session is not None:
        assert got == counts
        assert recorded_equal(session, reference)


@SETTINGS
@given(steps=corruptions)
def test_the_reference_reads_exactly_or_not_at_all(committed, reference, steps):
    session, got, _ = read_corrupted(REFERENCE, steps)
    if session is not None:
        assert got == committed                            # never silently fewer
        assert len(session.blocks) == REFERENCE_BLOCKS
        assert recorded_equal(session, reference)          # every chunk's CRC checked
