"""The flexible model builds its signals ``[u, ŷ]`` per window instead of for the whole run: the statistics, the
fit and the prediction are those of the whole-run signals sliced, bit for bit, whatever the operands' layouts
(a MATLAB record's voltages are Fortran-ordered)."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.diagnosis import flexible
from piezo_ff_ros.core.diagnosis.replay import Windows

FS = 5000.0


def _data(order_u, order_y, n=40_000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    u = np.stack([100 * np.sin(2 * np.pi * 3 * t) + rng.standard_normal(n), 80 * np.sign(np.sin(7 * t))], axis=1)
    y_nom = 1e-7 * np.cumsum(rng.standard_normal((n, 2)), axis=0) + u * 1e-7
    y = y_nom + 1e-8 * np.roll(u, 3, axis=0) + 1e-9 * rng.standard_normal((n, 2))
    return np.asarray(u, order=order_u), np.asarray(y, order=order_y), np.asarray(y_nom, order=order_y)


LAYOUTS = [("F", "C"), ("C", "C"), ("F", "F"), ("C", "F")]


@pytest.mark.parametrize("order_u,order_y", LAYOUTS)
@pytest.mark.parametrize("windows", [Windows.whole(40_000), Windows.spread(40_000, 8000, 4, 500),
                                     Windows([(1000, 3000, 40_000)])])
def test_window_signals_are_the_whole_run_signals_sliced(order_u, order_y, windows):
    u, _, y_nom = _data(order_u, order_y)
    sig = np.hstack([u, y_nom])
    sample = sig if windows.is_whole else windows.take(sig)
    sigs = [flexible._signals(u, y_nom, w, e) for w, _, e in windows.spans]
    mine = sigs[0] if windows.is_whole else \
        np.concatenate([sg[s - w:e - w] for sg, (w, s, e) in zip(sigs, windows.spans)])
    assert np.array_equal(mine, sample)
    assert (mine.flags.c_contiguous, mine.flags.f_contiguous) == (sample.flags.c_contiguous,
                                                                  sample.flags.f_contiguous)
    assert np.array_equal(np.std(mine, axis=0), np.std(sample, axis=0))
    for sg, (w, _, e) in zip(sigs, windows.spans):
        assert np.array_equal(sg, sig[w:e])


@pytest.mark.parametrize("order_u,order_y", LAYOUTS)
def test_prediction_is_the_whole_run_features_sliced(order_u, order_y):
    u, y, y_nom = _data(order_u, order_y)
    fit_win = Windows.spread(20_000, 8000, 4, 500)
    model = flexible.fit_flexible(u[:20_000], y[:20_000], y_nom[:20_000], fit_win, FS)
    score_win = Windows.spread(20_000, 8000, 4, 500, offset=20_000)
    got = model.predict(u, y_nom, score_win)
    # the prediction as computed from the whole-run signals
    sig = np.hstack([u, y_nom])
    m = sig.shape[1]
    outs = []
    for w, s, e in score_win.spans:
        d = -np.broadcast_to(model.mean @ model.theta, (e - s, model.theta.shape[1])).copy()
        for k, F in enumerate(flexible._feature_blocks(sig[w:e], model.filters, model.scale, slice(s - w, None))):
            d += F @ model.theta[k * m:(k + 1) * m]
        outs.append(d)
    assert np.array_equal(got, np.concatenate(outs))
