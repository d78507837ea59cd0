"""StreamBook (core/hardware/stream.py): stamps ↔ device samples, gaps, late and out-of-sequence blocks — pure."""
import numpy as np
import pytest

from piezo_ff_ros.core.hardware import StreamBook

P = 50_000


def book(max_gap=1000):
    return StreamBook(P, max_gap)


def test_contiguous_stream_maps_stamps_to_device_indices():
    b = book()
    assert b.classify(7 * P, 100, w=40).kind == "first"
    assert b.stamp_of(40) == 7 * P and b.stamp_of(139) == 106 * P
    assert b.classify(107 * P, 100, w=140).kind == "apply"
    assert b.split(30, 20) == [(10, 10, 7 * P)]          # samples before the stream have no stamp


def test_gap_is_filled_and_counted_late_is_dropped_or_trimmed():
    b = book()
    b.classify(0, 100, w=0)
    d = b.classify(300 * P, 100, w=100)
    assert d.kind == "gap" and d.fill == 200
    assert b.counters.gap_samples == 200 and b.counters.lost_blocks == 2
    assert b.classify(200 * P, 100, w=400).kind == "late"
    d = b.classify(350 * P, 100, w=400)
    assert d.kind == "trim" and d.skip == 50
    assert b.counters.late_blocks == 1 and b.counters.late_samples == 150


def test_one_future_stamped_block_costs_only_itself():
    """A block stamped far in the future costs only itself (it used to move the expected stamp there, so that every
    later block was dropped as late until ~/reset)."""
    b = book(max_gap=1000)
    b.classify(0, 100, w=0)
    assert b.classify(10 ** 9 * P, 100, w=100).kind == "pending"     # stray: held back, not applied
    for i in range(1, 50):
        assert b.classify(100 * i * P, 100, w=100 * i).kind == "apply"
    assert b.counters.out_of_sequence_blocks == 1 and b.counters.late_blocks == 0


def test_a_real_jump_is_followed_after_one_confirming_block_and_backward_restart_too():
    b = book(max_gap=1000)
    b.classify(0, 100, w=0)
    assert b.classify(10 ** 6 * P, 100, w=100).kind == "pending"
    d = b.classify((10 ** 6 + 100) * P, 100, w=100)
    assert d.kind == "confirm" and d.replay[0] == 10 ** 6 * P
    assert b.stamp_of(100) == 10 ** 6 * P and b.stamp_of(99) == 99 * P   # the old samples keep their stamps
    # a sender restarted at 0 without ~/reset: followed after confirmation
    b.classify(0, 100, w=300)
    assert b.classify(100 * P, 100, w=300).kind == "confirm"
    assert b.counters.rebases == 2


@pytest.mark.parametrize("seed", range(5))
def test_split_covers_every_stamped_sample_once_across_rebases(seed):
    rng = np.random.default_rng(seed)
    b = book()
    d, stamps = 10, {}
    b.rebase(d, 0)
    for _ in range(20):
        n = int(rng.integers(1, 300))
        for k in range(n):
            stamps[d + k] = b.stamp_of(d + k)
        d += n
        if rng.random() < 0.3:
            b.rebase(d, int(rng.integers(0, 10 ** 6)) * P)
    got = {}
    d0 = 0
    while d0 < d:
        n = int(rng.integers(1, 500))
        for off, cnt, stamp in b.split(d0, min(n, d - d0)):
            for j in range(cnt):
                assert d0 + off + j not in got
                got[d0 + off + j] = stamp + j * P
        d0 += n
    assert got == stamps


def test_off_grid_stamp_is_refused():
    b = book()
    b.classify(0, 10, w=0)
    with pytest.raises(ValueError, match="grid"):
        b.classify(10 * P + 7, 10, w=10)
