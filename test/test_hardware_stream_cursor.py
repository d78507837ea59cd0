"""StreamBook.classify with a write cursor before the stream's first segment: a one-line ValueError, not a
TypeError from ``stamp - None`` (found by mypy: ``stamp_of`` returns None there)."""
from __future__ import annotations

import pytest

from piezo_ff_ros.core.hardware.stream import StreamBook


def test_cursor_before_first_segment_is_a_clear_error():
    book = StreamBook(period_ns=50_000, max_gap=100)
    assert book.classify(1_000_000, 10, 100).kind == "first"     # the map starts at device index 100
    with pytest.raises(ValueError, match="device index 50 lies before the first segment"):
        book.classify(1_500_000, 10, 50)


def test_cursor_on_the_segment_still_classifies():
    book = StreamBook(period_ns=50_000, max_gap=100)
    book.classify(1_000_000, 10, 100)
    assert book.classify(1_000_000 + 10 * 50_000, 10, 110).kind == "apply"
