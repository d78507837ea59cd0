"""Trajectories: block invariance, durations, amplitudes, shapes, dict round trips, bad specs."""
import math

import numpy as np
import pytest

from piezo_ff_ros.core import trajectories as T
from piezo_ff_ros.core.config import ConfigError

FS = 20000.0

ALL = [
    T.Sine(amplitude=20e-6, frequency=0.1, axis="y", offset=1e-6, phase=0.3, duration=3.0),
    T.Step(amplitude=(20e-6, -5e-6), t_step=0.01, hold=0.5),
    T.Staircase(levels=(0.0, 5e-6, 10e-6, 2e-6), dwell=0.1, axis="x"),
    T.Circle(radius=30e-6, frequency=2.0, centre=(1e-6, -2e-6), revolutions=1.5),
    T.Raster(width=20e-6, lines=8, line_rate=20.0, turnaround=0.2),
    T.PRBS(amplitude=2e-6, clock_rate=900.0, seed=7, axis="all", duration=0.7),
    T.Multisine(amplitude=3e-6, f_min=2.0, f_max=300.0, n_tones=15, duration=1.0),
    T.Chirp(amplitude=1e-6, f0=1.0, f1=500.0, duration=0.8, method="logarithmic"),
    T.Spiral(radius=20e-6, frequency=10.0, revolutions=3, centre=(1e-6, 0.0)),
    T.Table(values=np.random.default_rng(3).normal(0, 1e-6, (257, 2)), sample_rate=FS),
    T.Hold(value={"y": 3e-6}, duration=0.2),
]


@pytest.mark.parametrize("traj", ALL, ids=lambda t: t.kind)
def test_block_invariance_random_splits(traj):
    rng = np.random.default_rng(1)
    n = traj.n_samples(FS) + 37  # run past the end: held last sample
    whole = traj.block(0, n, FS)
    for _ in range(3):
        cuts = np.sort(rng.choice(np.arange(1, n), size=6, replace=False))
        edges = np.r_[0, cuts, n]
        parts = [traj.block(a, b - a, FS) for a, b in zip(edges[:-1], edges[1:])]
        assert np.array_equal(np.vstack(parts), whole)
    assert whole.shape == (n, 2)
    assert np.array_equal(whole[-1], whole[traj.n_samples(FS) - 1])


@pytest.mark.parametrize("traj", ALL, ids=lambda t: t.kind)
def test_dict_round_trip(traj):
    again = T.from_dict(traj.to_dict())
    assert again == traj
    assert np.array_equal(again.block(0, 500, FS), traj.block(0, 500, FS))


def test_durations_and_sample_counts():
    assert T.Step(t_step=0.05, hold=600.0).n_samples(FS) == int(600.05 * FS)
    assert T.Circle(frequency=0.5, revolutions=3).duration == pytest.approx(6.0)
    assert T.Raster(lines=10, line_rate=5.0).duration == pytest.approx(2.0)
    assert T.Staircase(levels=(1, 2, 3), dwell=0.5).duration == pytest.approx(1.5)
    assert math.isinf(T.Sine().duration) and math.isinf(T.Sine().n_samples(FS))
    with pytest.raises(ValueError):
        T.Sine().sample(FS)


def test_sine_amplitude_offset_and_axis():
    tr = T.Sine(amplitude=20e-6, frequency=10.0, axis="y", offset=1e-6, duration=1.0)
    _, v = tr.sample(FS)
    assert np.all(v[:, 0] == 0)
    assert v[:, 1].max() == pytest.approx(21e-6, rel=1e-6)
    assert v[:, 1].min() == pytest.approx(-19e-6, rel=1e-6)
    assert v[0, 1] == pytest.approx(1e-6)


def test_step_levels_and_timing():
    tr = T.Step(amplitude={"x": 20e-6}, t_step=0.01, hold=0.1)
    _, v = tr.sample(FS)
    k = tr.step_index(FS)
    assert k == 200
    assert np.all(v[:k] == 0) and np.all(v[k:, 0] == 20e-6) and np.all(v[:, 1] == 0)


def test_staircase_levels():
    tr = T.Staircase(levels=(0.0, 5e-6, 10e-6), dwell=0.1, axis="x")
    _, v = tr.sample(FS)
    assert np.array_equal(np.unique(v[:, 0]), [0.0, 5e-6, 10e-6])
    assert v[2000, 0] == 5e-6 and v[1999, 0] == 0.0


def test_circle_radius_and_centre():
    tr = T.Circle(radius=20e-6, frequency=1.0, centre=(2e-6, -1e-6), revolutions=1)
    _, v = tr.sample(FS)
    r = np.hypot(v[:, 0] - 2e-6, v[:, 1] + 1e-6)
    np.testing.assert_allclose(r, 20e-6, rtol=1e-12)
    # x leads by a quarter turn: starts at (cx, cy + r)
    np.testing.assert_allclose(v[0], [2e-6, 19e-6], atol=1e-15)


def test_raster_spans_width_and_turnarounds_are_smooth():
    tr = T.Raster(width=20e-6, lines=4, line_rate=10.0, height=8e-6, turnaround=0.1)
    _, v = tr.sample(FS)
    assert v[:, 0].max() == pytest.approx(10e-6, rel=1e-6) and v[:, 0].min() == pytest.approx(-10e-6, rel=1e-6)
    assert v[0, 1] == pytest.approx(-4e-6) and v[-1, 1] == pytest.approx(4e-6, rel=1e-3)
    vel = np.diff(v[:, 0]) * FS
    acc = np.diff(vel) * FS
    # constant speed on the lines, bounded acceleration at the turnarounds (no velocity jump)
    v_line = 2 * 20e-6 * 10.0 / (1 - 0.1)
    assert np.abs(vel).max() == pytest.approx(v_line, rel=1e-3)
    assert np.abs(acc).max() < 1.01 * 2 * v_line / (0.1 / 10.0)


def test_prbs_levels_clock_and_balance():
    tr = T.PRBS(amplitude=2e-6, clock_rate=1000.0, seed=3, axis="x", offset=1e-6, order=9, duration=511 / 1000.0)
    _, v = tr.sample(FS)
    assert set(np.unique(v[:, 0])) == {-1e-6, 3e-6}
    chips = v[::20, 0]
    assert len(chips) == 511
    # maximal-length sequence: one more +1 than −1 chip per period
    assert (chips > 1e-6).sum() - (chips < 1e-6).sum() == 1
    # constant within a chip
    assert np.all(v[:20, 0] == v[0, 0])
    other = T.PRBS(amplitude=2e-6, clock_rate=1000.0, seed=4, axis="x", order=9, duration=0.5)
    assert not np.array_equal(other.block(0, 10000, FS), T.PRBS(amplitude=2e-6, clock_rate=1000.0, seed=3,
                                                                  axis="x", order=9, duration=0.5).block(0, 10000, FS))


def test_multisine_rms_and_band():
    tr = T.Multisine(amplitude=2e-6, f_min=10.0, f_max=100.0, n_tones=10, duration=1.0)
    _, v = tr.sample(FS)
    assert np.sqrt(np.mean(v[:, 0] ** 2)) == pytest.approx(2e-6, rel=1e-3)
    spec = np.abs(np.fft.rfft(v[:, 0]))
    f = np.fft.rfftfreq(len(v), 1 / FS)
    assert f[np.argmax(spec)] in tr.frequencies
    assert spec[f > 150].max() < 1e-3 * spec.max()
    # Schroeder phases give a lower crest factor than zero phases
    crest = np.abs(v[:, 0]).max() / 2e-6
    assert crest < np.sqrt(2 * 10) * 0.7


def test_chirp_frequency_sweep():
    for method in ("linear", "logarithmic"):
        tr = T.Chirp(amplitude=1e-6, f0=5.0, f1=50.0, duration=2.0, method=method)
        t, v = tr.sample(FS)
        assert np.abs(v[:, 0]).max() == pytest.approx(1e-6, rel=1e-4)
        zc = t[np.nonzero(np.diff(np.signbit(v[1:, 0])))[0] + 1]
        f_measured = 1 / (2 * np.diff(zc))
        f_expected = tr.instantaneous_frequency(0.5 * (zc[1:] + zc[:-1]))
        np.testing.assert_allclose(f_measured, f_expected, rtol=0.03)
        assert f_measured[0] < 8.0 and f_measured[-1] > 40.0


def test_sequence_segments_and_lookup():
    seq = T.TrajectorySequence([("rest", T.Hold(duration=0.1), {}),
                      ("step", T.Step(amplitude=(1e-6, 0), t_step=0.0, hold=0.2), {"stages": ["hysteresis"]}),
                      ("circle", T.Circle(radius=1e-6, revolutions=1, frequency=10.0), {"metric": "tracking"})])
    assert seq.n_samples(FS) == 2000 + 4000 + 2000
    assert seq.segment_at(1999, FS).name == "rest"
    assert seq.segment_at(2000, FS).name == "step"
    assert seq.segment_at(7999, FS).name == "circle"
    assert seq.segment("step", FS).meta["stages"] == ["hysteresis"]
    v = seq.block(0, seq.n_samples(FS), FS)
    assert np.all(v[:2000] == 0) and np.all(v[2000:6000, 0] == 1e-6)
    np.testing.assert_allclose(v[6000], [0.0, 1e-6], atol=1e-18)  # circle restarts at its own t = 0
    again = T.from_dict(seq.to_dict())
    assert again == seq and again.segment("step", FS).meta == {"stages": ["hysteresis"]}


def test_from_dict_units_and_errors():
    tr = T.from_dict({"type": "circle", "radius": 20, "centre": [1, 2], "unit": "um", "frequency": 1})
    assert tr.radius == pytest.approx(20e-6) and tr.centre == pytest.approx((1e-6, 2e-6))
    assert math.isinf(T.from_dict({"type": "sine", "duration": "inf"}).duration)
    with pytest.raises(ConfigError, match=r"^trajectory\.type"):
        T.from_dict({"type": "lissajous"})
    with pytest.raises(ConfigError, match=r"^trajectory\.frequency"):
        T.from_dict({"type": "sine", "frequency": 0})
    with pytest.raises(ConfigError, match=r"^trajectory\.amplitude"):
        T.from_dict({"type": "sine", "amplitude": float("nan")})
    with pytest.raises(ConfigError, match=r"^trajectory\.radios"):
        T.from_dict({"type": "circle", "radios": 1})
    with pytest.raises(ConfigError, match=r"^trajectory\.segments\[0\]\.trajectory\.duration"):
        T.from_dict({"type": "sequence", "segments": [{"name": "a", "trajectory": {"type": "sine"}},
                                                        {"name": "b", "trajectory": {"type": "hold"}}]})
    with pytest.raises(ConfigError, match=r"axis"):
        T.Sine(axis="z")


# -- tables played sample-exactly, workspace ---------------------------------------------------------------------

def test_table_is_sample_exact_at_its_rate_and_interpolates_at_another(tmp_path):
    vals = np.random.default_rng(0).normal(0, 1e-6, (1000, 2))
    tab = T.Table(values=vals, sample_rate=FS)
    assert tab.n_samples(FS) == 1000
    np.testing.assert_array_equal(tab.block(0, 1000, FS), vals)          # bit-exact, no resampling
    np.testing.assert_array_equal(tab.block(999, 3, FS), vals[[999, 999, 999]])   # held after the end
    half = tab.block(0, 500, FS / 2)                                      # every other sample at half the rate
    np.testing.assert_allclose(half, vals[::2], rtol=0, atol=1e-22)
    mid = tab.block(1, 1, 2 * FS)                                         # halfway between samples 0 and 1
    np.testing.assert_allclose(mid[0], 0.5 * (vals[0] + vals[1]), rtol=1e-12)
    np.save(tmp_path / "t.npy", vals)
    from_file = T.from_dict({"type": "table", "file": str(tmp_path / "t.npy"), "sample_rate": FS})
    np.testing.assert_array_equal(from_file.block(0, 1000, FS), vals)


def test_table_csv_columns_by_name_and_errors_name_the_row(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("y,x\n1e-6,2e-6\n3e-6,4e-6\n")
    tab = T.from_dict({"type": "table", "file": str(p), "sample_rate": 1000.0})
    np.testing.assert_array_equal(tab.block(0, 2, 1000.0), [[2e-6, 1e-6], [4e-6, 3e-6]])   # x first, by name
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z\n1,2\n")
    with pytest.raises(ConfigError, match=r"^trajectory\.file: .*no column named 'y'"):
        T.from_dict({"type": "table", "file": str(bad)})
    with pytest.raises(ConfigError, match=r"^trajectory\.values: row 1"):
        T.from_dict({"type": "table", "values": [[0, 0], [float("nan"), 0]]})
    with pytest.raises(ConfigError, match=r"^trajectory\.file: .*no such file"):
        T.from_dict({"type": "table", "file": str(tmp_path / "missing.npy")})
    with pytest.raises(ConfigError, match=r"^trajectory\.values: give exactly one"):
        T.from_dict({"type": "table"})


@pytest.mark.parametrize("traj", ALL, ids=lambda t: t.kind)
def test_bound_is_an_upper_bound(traj):
    n = min(traj.n_samples(FS), 40000)
    peak = np.abs(traj.block(0, int(n), FS)).max(axis=0)
    assert np.all(peak <= np.array(traj.bound()) * (1 + 1e-12) + 1e-18)


def test_workspace_refuses_a_metre_circle_and_checks_voltage_segments_in_volts():
    with pytest.raises(ConfigError, match=r"^trajectory\.radius: reaches 1 on axis x, outside the workspace"):
        T.check_trajectory_peaks(T.from_dict({"type": "circle", "radius": 1.0}), 1e-4)
    T.check_trajectory_peaks(T.from_dict({"type": "circle", "radius": 20, "unit": "um"}), 1e-4)   # fine
    T.check_trajectory_peaks(T.from_dict({"type": "circle", "radius": 1.0}), 0.0)                 # 0: disabled
    seq = T.TrajectorySequence([("hyst", T.Sine(amplitude=200.0, frequency=0.1, duration=10.0), {"input": "voltage"}),
                      ("circle", T.Circle(radius=20e-6), {"input": "reference"})])
    T.check_trajectory_peaks(seq, 1e-4, voltage_limit=200.0)
    with pytest.raises(ConfigError, match=r"segments\[0\]\.trajectory\.amplitude"):
        T.check_trajectory_peaks(seq, 1e-4, voltage_limit=100.0)
