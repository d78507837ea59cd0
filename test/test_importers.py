"""CSV/.mat importers: round trip in SI, and located errors for bad files."""
import numpy as np
import pytest
import scipy.io

from piezo_ff_ros.core.recording.importers import load_csv, load_mat
from piezo_ff_ros.core.identification.goodness_of_fit import fit_percent


def _write_csv(path, rows, header="t,u_x,u_y,x,y"):
    path.write_text(header + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    return path


def _good(n=50):
    t = np.arange(n) * 1e-3
    return np.column_stack([t, 100 * np.sin(t), 50 * np.cos(t), 1e-5 * np.sin(t), 2e-6 * np.cos(t)])


def test_csv_round_trip(tmp_path):
    d = _good()
    r = load_csv(_write_csv(tmp_path / "a.csv", d))
    assert r.axes == ("x", "y")
    np.testing.assert_allclose(r.u, d[:, 1:3])
    np.testing.assert_allclose(r.y, d[:, 3:5])
    assert r.dt == pytest.approx(1e-3)


def test_csv_three_axes(tmp_path):
    d = _good()
    rows = np.column_stack([d[:, 0], d[:, 1], d[:, 2], d[:, 1], d[:, 3], d[:, 4], d[:, 3]])
    r = load_csv(_write_csv(tmp_path / "b.csv", rows, "t,u_x,u_y,u_z,x,y,z"))
    assert r.axes == ("x", "y", "z") and r.u.shape == (50, 3)


@pytest.mark.parametrize("mutate, expect", [
    (lambda d: d.__setitem__((7, 3), np.nan), "column 'x': NaN at row 9"),
    (lambda d: d.__setitem__((10, 0), d[10, 0] + 4e-4), "non-uniform sampling at row"),
    (lambda d: d.__setitem__((slice(None), 4), d[:, 4] * 1e6), "looks like µm"),
    (lambda d: d.__setitem__((slice(None), 1), d[:, 1] * 1e3), "kV-scale"),
])
def test_csv_bad_files_say_what_and_where(tmp_path, mutate, expect):
    d = _good()
    mutate(d)
    with pytest.raises(ValueError, match=expect):
        load_csv(_write_csv(tmp_path / "bad.csv", d))


def test_csv_missing_column(tmp_path):
    d = _good()[:, [0, 1, 2, 3]]
    with pytest.raises(ValueError, match=r"missing displacement column\(s\) \['y'\]"):
        load_csv(_write_csv(tmp_path / "m.csv", d, "t,u_x,u_y,x"))


def test_mat_round_trip_and_errors(tmp_path):
    d = _good()
    p = tmp_path / "a.mat"
    scipy.io.savemat(p, {"t": d[:, 0], "u": d[:, 1:3], "y": d[:, 3:5]})
    r = load_mat(p)
    np.testing.assert_allclose(r.y, d[:, 3:5])
    scipy.io.savemat(p, {"t": d[:, 0], "u": d[:, 1:3]})
    with pytest.raises(ValueError, match=r"missing variable\(s\) \['y'\]"):
        load_mat(p)
    yy = d[:, 3:5].copy()
    yy[4, 1] = np.inf
    scipy.io.savemat(p, {"t": d[:, 0], "u": d[:, 1:3], "y": yy})
    with pytest.raises(ValueError, match=r"y\(:,2\).*Inf at row 5"):
        load_mat(p)


def test_fit_percent_matches_definition():
    y = np.sin(np.linspace(0, 6, 100))
    assert fit_percent(y, y)[0] == pytest.approx(100.0)
    assert fit_percent(y, np.full_like(y, y.mean()))[0] == pytest.approx(0.0)
    e = 0.1 * np.cos(np.linspace(0, 6, 100))
    expect = 100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean()))
    assert fit_percent(y, y + e)[0] == pytest.approx(expect)
