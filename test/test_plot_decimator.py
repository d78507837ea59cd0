"""The plot decimator: same kept instants whatever the block split, one grid for every stream, the tracking
error where reference and displacement meet, bad settings refused with one line."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezo_ff_ros.core.plot_decimator import PlotDecimator, StampDecimator

PERIOD = 50_000
FS = 20_000.0


def _feed_split(dec, stream, t0, data, cuts):
    out, i = [], 0
    for c in [*sorted(set(cuts)), data.shape[0]]:
        if c > i:
            out += dec.feed(stream, t0 + i * PERIOD, data[i:c])
            i = c
    return out


@settings(max_examples=60, deadline=None)
@given(cuts=st.lists(st.integers(1, 999), max_size=12), t0_index=st.integers(0, 10 ** 12))
def test_kept_samples_do_not_depend_on_the_block_split(cuts, t0_index):
    data = np.column_stack([np.arange(1000.0), -np.arange(1000.0)])
    t0 = t0_index * PERIOD
    whole = PlotDecimator(FS, 100.0).feed("voltage", t0, data)
    split = _feed_split(PlotDecimator(FS, 100.0), "voltage", t0, data, cuts)
    assert [(t, s, x.tolist()) for t, s, x in whole] == [(t, s, x.tolist()) for t, s, x in split]
    assert all(((s // PERIOD) % 200) == 0 for _, s, _ in whole)     # 100 Hz of 20 kHz: every 200th grid sample
    assert len(whole) in (4, 5, 6)


def test_error_is_reference_minus_displacement_at_the_same_instant_in_any_arrival_order():
    dec = PlotDecimator(FS, 1000.0)
    ref = np.column_stack([np.linspace(0, 1e-5, 400), np.zeros(400)])
    disp = 0.9 * ref
    out = dec.feed("displacement", 10 * PERIOD, disp[:250]) + dec.feed("reference", 10 * PERIOD, ref)
    out += dec.feed("displacement", 260 * PERIOD, disp[250:])
    err = {s: x for t, s, x in out if t == "error"}
    kept = {s for t, s, _ in out if t == "reference"}
    assert kept == set(err) and len(err) == 20
    for s, e in err.items():
        i = s // PERIOD - 10
        np.testing.assert_allclose(e, ref[i] - disp[i], rtol=0, atol=0)


def test_waiting_instants_are_bounded():
    dec = PlotDecimator(FS, FS, pending=50)
    dec.feed("reference", 0, np.zeros((1000, 2)))
    assert len(dec._waiting["reference"]) == 50


@pytest.mark.parametrize("kwargs, word", [({"rate": 0.0}, "rate"), ({"rate": 3e4}, "rate"),
                                          ({"rate": float("nan")}, "rate"), ({"sample_rate": -1.0}, "sample_rate")])
def test_bad_settings_are_one_line_naming_the_field(kwargs, word):
    with pytest.raises(ValueError, match=f"^{word}") as exc:
        PlotDecimator(**{"sample_rate": FS, "rate": 100.0, **kwargs})
    assert "\n" not in str(exc.value)


def test_unknown_stream_and_bad_block_refused():
    dec = PlotDecimator(FS, 100.0)
    with pytest.raises(ValueError, match="^stream"):
        dec.feed("voltages", 0, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="block"):
        StampDecimator(PERIOD, 2).pick(0, np.zeros(3))
