"""Columns read by name, unit and magnitude mistakes refused naming the field.

Each case was accepted before (silently wrong): CSV ``t,u_y,u_x,y,x`` taken with x/y swapped, a block with fields
``[y, x]`` applied swapped, voltages in kV, time in ms, ``units.voltage: kV`` ignored, misspelled and duplicate
YAML keys, ``order: 12.5`` → 12, 30 kHz, ``hysteresis.Dp`` 10⁷ × nominal.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from piezo_ff_ros.core.config import ConfigError, PiezoConfig, load_config
from piezo_ff_ros.core.recording import load_run
from piezo_ff_ros.core.recording.importers import load_csv, load_mat

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "pt230_94.yaml"


def _run_arrays(n=400, fs=20000.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    u = np.column_stack([100 * np.sin(2 * np.pi * 5 * t), 40 * np.cos(2 * np.pi * 3 * t)]) + rng.normal(0, 1, (n, 2))
    y = u * 1.7e-7 + rng.normal(0, 1e-9, (n, 2))
    return t, u, y


def _csv(path: Path, header: list[str], cols: dict) -> Path:
    rows = np.column_stack([cols[h] for h in header])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    return path


def _cols(t, u, y):
    return {"t": t, "u_x": u[:, 0], "u_y": u[:, 1], "x": y[:, 0], "y": y[:, 1]}


# ---------------------------------------------------------------------------------------------------------------
# item 4: by name

def test_csv_columns_in_any_order_give_the_same_run(tmp_path):
    t, u, y = _run_arrays()
    a = load_csv(_csv(tmp_path / "a.csv", ["t", "u_x", "u_y", "x", "y"], _cols(t, u, y)))
    b = load_csv(_csv(tmp_path / "b.csv", ["t", "u_y", "u_x", "y", "x"], _cols(t, u, y)))
    c = load_csv(_csv(tmp_path / "c.csv", ["y", "u_y", "t", "x", "u_x"], _cols(t, u, y)))
    for r in (a, b, c):
        assert r.axes == ("x", "y")
        assert np.array_equal(r.u, u) and np.array_equal(r.y, y) and np.array_equal(r.t, t)


def test_csv_axes_can_be_asked_by_name(tmp_path):
    t, u, y = _run_arrays()
    r = load_csv(_csv(tmp_path / "a.csv", ["t", "u_x", "u_y", "x", "y"], _cols(t, u, y)), axes=("y", "x"))
    assert r.axes == ("y", "x") and np.array_equal(r.u, u[:, ::-1])
    with pytest.raises(ValueError, match=r"a.csv.*axis 'z'.*no column 'u_z'"):
        load_csv(tmp_path / "a.csv", axes=("x", "z"))


@pytest.mark.parametrize("header, expect", [
    (["t", "u_x", "u_y", "x", "x"], r"duplicate column\(s\) \['x'\]"),
    (["t", "u_x", "u_y", "x"], r"missing displacement column\(s\) \['y'\]"),
    (["t", "u_x", "u_y", "x", "y", "temp"], r"unknown column\(s\) \['temp'\]"),
    (["t", "u_x", "u_y", "x", "y", "r_x"], r"reference columns.*missing \['r_y'\]"),
    (["time", "u_x", "u_y", "x", "y"], r"missing column 't'"),
])
def test_csv_header_errors_name_the_column(tmp_path, header, expect):
    t, u, y = _run_arrays(50)
    cols = dict(_cols(t, u, y), temp=t * 0 + 20, r_x=y[:, 0], time=t)
    path = tmp_path / "h.csv"
    path.write_text(",".join(header) + "\n" + "\n".join(
        ",".join(repr(float(cols.get(h, t)[i])) for h in header) for i in range(50)) + "\n")
    with pytest.raises(ValueError, match=expect):
        load_csv(path)


def test_mat_axes_variable_is_honoured_by_name(tmp_path):
    import scipy.io

    t, u, y = _run_arrays()
    p = tmp_path / "r.mat"
    scipy.io.savemat(p, {"t": t, "u": u[:, ::-1], "y": y[:, ::-1], "axes": np.array(["y", "x"], dtype=object)})
    r = load_mat(p)
    assert r.axes == ("x", "y") and np.array_equal(r.u, u) and np.array_equal(r.y, y)


def test_node_unpack_block_maps_fields_by_name():
    pytest.importorskip("rclpy")
    from piezo_ff_ros.nodes.common import BlockFormatError, pack_block, unpack_block

    blk = np.arange(10.0).reshape(5, 2)
    msg = pack_block(blk[:, ::-1], ["y", "x"], 0)  # fields [y, x]
    assert np.array_equal(unpack_block(msg, ["x", "y"]), blk)
    for axes in (["x"], ["x", "z"], ["x", "y", "z"]):
        with pytest.raises(BlockFormatError, match="do not name the axes"):
            unpack_block(msg, axes)
    dup = pack_block(blk, ["x", "y"], 0)   # a peer's own packing: two fields named x
    dup.fields[1].name = "x"
    with pytest.raises(BlockFormatError, match="duplicate"):
        unpack_block(dup, ["x", "y"])


# ---------------------------------------------------------------------------------------------------------------
# item 7: units and magnitudes in data files

def test_csv_voltages_in_kv_are_refused(tmp_path):
    t, u, y = _run_arrays()
    with pytest.raises(ValueError, match=r"column 'u_[xy]'.*looks like kV"):
        load_csv(_csv(tmp_path / "kv.csv", ["t", "u_x", "u_y", "x", "y"], _cols(t, u / 1000, y)))
    # an axis not driven at all (zeros) is fine
    u0 = u.copy()
    u0[:, 1] = 0.0
    assert load_csv(_csv(tmp_path / "z.csv", ["t", "u_x", "u_y", "x", "y"], _cols(t, u0, y))).u[:, 1].max() == 0


def test_csv_time_in_ms_is_refused(tmp_path):
    t, u, y = _run_arrays()
    with pytest.raises(ValueError, match=r"column 't'.*ms"):
        load_csv(_csv(tmp_path / "ms.csv", ["t", "u_x", "u_y", "x", "y"], _cols(t * 1000, u, y)))


def test_mat_voltages_in_kv_are_refused(tmp_path):
    import scipy.io

    t, u, y = _run_arrays()
    p = tmp_path / "kv.mat"
    scipy.io.savemat(p, {"t": t, "u": u / 1000, "y": y})
    with pytest.raises(ValueError, match=r"kv.mat.*u\(:,[12]\).*looks like kV"):
        load_mat(p)


# ---------------------------------------------------------------------------------------------------------------
# item 7: YAML configs

def _paper_dict() -> dict:
    return yaml.safe_load(PAPER.read_text())


def _write_yaml(tmp_path, d, name="c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def test_units_voltage_kv_is_refused(tmp_path):
    d = _paper_dict()
    d["units"]["voltage"] = "kV"
    with pytest.raises(ConfigError, match=r"^units.voltage: .*'kV'"):
        load_config(_write_yaml(tmp_path, d))
    d["units"]["voltage"] = "V"
    d["units"]["time"] = "ms"
    with pytest.raises(ConfigError, match=r"^units.time: unknown key"):
        load_config(_write_yaml(tmp_path, d))


@pytest.mark.parametrize("path, bad, hint", [
    (("vibration",), "gama_max", "gamma_max"),
    (("hysteresis",), "Gama", "Gamma"),
    (("limits",), "voltge", "voltage"),
    (("cascade",), "hysteresis_lop", "hysteresis_loop"),
    ((), "sample_rte", "sample_rate"),
    (("dynamics", "G_L", "xx"), "dne", "den"),
])
def test_misspelled_keys_are_refused_naming_them(tmp_path, path, bad, hint):
    d = _paper_dict()
    sec = d
    for k in path:
        sec = sec[k]
    sec[bad] = sec.get(hint, 1.0)
    name = ".".join(path + (bad,))
    with pytest.raises(ConfigError, match=rf"^{name}: unknown key.*'{hint}'"):
        load_config(_write_yaml(tmp_path, d))


def test_duplicate_yaml_keys_are_refused_with_the_line(tmp_path):
    text = PAPER.read_text().replace("  eps_s: 0.01\n", "  eps_s: 0.01\n  eps_s: 0.5\n")
    p = tmp_path / "dup.yaml"
    p.write_text(text)
    line = text.splitlines().index("  eps_s: 0.5") + 1
    with pytest.raises(ConfigError, match=rf"dup.yaml.*line {line}.*duplicate key 'eps_s'"):
        load_config(p)


@pytest.mark.parametrize("value", [12.5, "12", True, 0, -3])
def test_order_must_be_a_positive_integer(tmp_path, value):
    d = _paper_dict()
    d["vibration"]["order"] = value
    with pytest.raises(ConfigError, match=r"^vibration.order: "):
        load_config(_write_yaml(tmp_path, d))


def test_order_12_0_is_accepted(tmp_path):
    d = _paper_dict()
    d["vibration"]["order"] = 12.0
    assert load_config(_write_yaml(tmp_path, d)).vibration.order == 12


@pytest.mark.parametrize("fs", [30000.0, 3.0e9, 1e-3])
def test_sample_rate_without_whole_nanosecond_period_is_refused(tmp_path, fs):
    d = _paper_dict()
    d["sample_rate"] = fs
    with pytest.raises(ConfigError, match=r"^sample_rate: "):
        load_config(_write_yaml(tmp_path, d))
    with pytest.raises(ConfigError, match=r"^sample_rate: "):
        load_config(PAPER).with_sample_rate(fs)


@pytest.mark.parametrize("fs", [20000.0, 10000.0, 25000.0, 50000.0])
def test_documented_sample_rates_are_accepted(fs):
    assert load_config(PAPER).with_sample_rate(fs).sample_rate == fs


def test_implausible_hysteresis_gain_is_refused_at_load_and_at_runtime(tmp_path):
    from piezo_ff_ros.core.param_map import params_to_config

    base = load_config(PAPER)
    with pytest.raises(ConfigError, match=r"^hysteresis.Dp: .*m/V"):
        params_to_config({"hysteresis.Dp": [1.0, 0.0, 0.0, 1.0]}, base)  # 10⁷ × nominal, the case
    d = _paper_dict()
    d["hysteresis"]["Dp"] = [[1.663e6, 0], [0, 1.803e6]]  # µm/V as written: 1.7 m/V
    with pytest.raises(ConfigError, match=r"^hysteresis.Dp: "):
        load_config(_write_yaml(tmp_path, d))
    d = _paper_dict()
    d["hysteresis"]["B"] = [[73.0, 0.0], [0.0, 54.0]]
    with pytest.raises(ConfigError, match=r"^hysteresis.B: "):
        load_config(_write_yaml(tmp_path, d))
    # nominal values pass, at load and through the runtime parameter path
    assert params_to_config({"hysteresis.Dp": [1.663e-7, 5.4e-9, -4.8e-9, 1.803e-7]}, base).hysteresis.Dp


@pytest.mark.parametrize("key, value", [("voltage", 1e9), ("slew", 1e15), ("stale_timeout", 1e6)])
def test_implausible_limits_are_refused(tmp_path, key, value):
    d = _paper_dict()
    d["limits"][key] = value
    with pytest.raises(ConfigError, match=rf"^limits.{key}: "):
        load_config(_write_yaml(tmp_path, d))


@pytest.mark.parametrize("key, value", [("sample_rate", "fast"), ("axes", "xy"), ("name", ["a"]),
                                        ("limits", [1, 2]), ("vibration", 3)])
def test_wrong_types_name_the_field(tmp_path, key, value):
    d = _paper_dict()
    d[key] = value
    with pytest.raises(ConfigError, match=rf"^{key}"):
        load_config(_write_yaml(tmp_path, d))


def test_paper_config_and_variants_still_load_and_round_trip():
    cfg = load_config(PAPER)
    assert load_config(PAPER, variant="gyx_gain_div10").variant == "gyx_gain_div10"
    again = PiezoConfig.from_dict(cfg.to_dict(length_unit="m"))
    assert again.hysteresis == cfg.hysteresis and again.limits == cfg.limits
    assert load_run  # the loaders share the same checks (used by the property tests)
