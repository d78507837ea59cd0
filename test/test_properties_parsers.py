"""Property-based tests (Hypothesis) of every parser and boundary of the recording/config layer.

The property, everywhere: a bad input gives a clear error (a ``ValueError`` naming the file, field or row) or a
correct result — never another exception type (a traceback in the CLI), never a silently wrong result.

- CSV: any column order gives the same run; any cell/header mutation is refused naming the row/column or loads
  the values actually written.
- .mat: random shapes, orientations, missing/non-numeric variables.
- MCAP: cut at any byte, bytes flipped inside the CRC-protected data (chunks) or the record framing, foreign
  message types on the contract's topic names: an error naming the file, or every sample read equals the
  sample written at the same index.  (MCAP Metadata records carry no CRC in the format; a flipped digit there is
  undetectable by any reader, so flips are aimed at the data section; flips anywhere must still give a ValueError
  or a run.)  ``piezo-ff recover`` of any cut/damaged file opens in the strict ``mcap`` and ``rosbags`` readers and
  keeps every sample ``read_run`` reads from the damaged file.
- YAML configs: a random leaf set to a random value, a key removed or misspelled: ``ConfigError`` naming the
  section, or the value loads exactly as given (no rounding).
- block messages: pack/unpack round trips with any field order; any contract violation is refused naming the
  ``block.`` field.
- runtime parameters: random values for every parameter go through config validation: ``ConfigError`` naming
  the parameter, or a valid config.

Bounded example counts keep the file well under a minute.
"""
from __future__ import annotations

import copy
import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, assume, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from piezo_ff_ros.core.config import ConfigError, PiezoConfig, load_config  # noqa: E402
from piezo_ff_ros.core.recording import blocks as B  # noqa: E402
from piezo_ff_ros.core.recording.importers import load_csv, load_mat  # noqa: E402
from piezo_ff_ros.core.recording.mcap_io import McapRecorder, read_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "pt230_94.yaml"


def _settings(n: int):
    """``n`` examples, no deadline, no example database on disk; derandomized under CI (reproducible runs),
    random otherwise (new inputs at every local run)."""
    return settings(max_examples=n, deadline=None, database=None, derandomize=bool(os.environ.get("CI")),
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


FAST = _settings(30)


def _tmp(tmp_path_factory, name: str) -> Path:
    return tmp_path_factory.mktemp("prop") / name


# ---------------------------------------------------------------------------------------------------------------
# CSV

AXES_POOL = ("x", "y", "z", "theta")


@st.composite
def csv_runs(draw):
    n = draw(st.integers(2, 40))
    axes = draw(st.lists(st.sampled_from(AXES_POOL), min_size=1, max_size=3, unique=True))
    fs = draw(st.sampled_from([1000.0, 20000.0, 25000.0]))
    t = np.arange(n) / fs + draw(st.floats(0, 10))
    amp = draw(st.floats(10.0, 190.0))
    u = draw(st.lists(st.floats(-1, 1), min_size=n * len(axes), max_size=n * len(axes)))
    u = np.array(u).reshape(n, len(axes)) * amp
    u[0, 0] = amp  # the drive reaches its amplitude (a run in V, not kV)
    y = u * 1.7e-7
    cols = {"t": t}
    for i, a in enumerate(axes):
        cols[f"u_{a}"], cols[a] = u[:, i], y[:, i]
    order = draw(st.permutations(list(cols)))
    delim = draw(st.sampled_from([",", ";", "\t"]))
    return cols, order, delim, axes


def _csv_text(cols, order, delim):
    n = len(cols["t"])
    return delim.join(order) + "\n" + "\n".join(delim.join(repr(float(cols[h][i])) for h in order)
                                                for i in range(n)) + "\n"


@FAST
@given(csv_runs())
def test_csv_any_column_order_reads_the_same(tmp_path_factory, run):
    cols, order, delim, axes = run
    p = _tmp(tmp_path_factory, "r.csv")
    p.write_text(_csv_text(cols, order, delim))
    r = load_csv(p)
    expected = tuple(a for a in ("x", "y", "z") if a in axes) + tuple(a for a in order if a in axes
                                                                       and a not in ("x", "y", "z"))
    assert r.axes == expected
    for i, a in enumerate(r.axes):
        assert np.array_equal(r.u[:, i], cols[f"u_{a}"]) and np.array_equal(r.y[:, i], cols[a])
    assert np.array_equal(r.t, cols["t"])


BAD_CELLS = st.sampled_from(["", "nan", "inf", "-inf", "abc", "1,2", "0x10", "1e999", "'", "NaN", "None", " "])


@FAST
@given(csv_runs(), st.data())
def test_csv_mutated_cell_is_refused_naming_row_and_column_or_read_as_written(tmp_path_factory, run, data):
    cols, order, delim, _ = run
    n = len(cols["t"])
    row = data.draw(st.integers(0, n - 1))
    col = data.draw(st.sampled_from(order))
    bad = data.draw(BAD_CELLS)
    lines = _csv_text(cols, order, delim).splitlines()
    cells = lines[row + 1].split(delim)
    cells[order.index(col)] = bad
    lines[row + 1] = delim.join(cells)
    p = _tmp(tmp_path_factory, "m.csv")
    p.write_text("\n".join(lines) + "\n")
    try:
        r = load_csv(p)
    except ValueError as exc:
        msg = str(exc)
        assert str(p) in msg
        assert f"row {row + 2}" in msg or f"column {col!r}" in msg or "field(s)" in msg or "header" in msg, msg
    else:  # accepted: only if the cell still parses to a finite value that was written
        v = float(bad)
        assert math.isfinite(v)
        got = r.t[row] if col == "t" else (r.u[row, r.axes.index(col[2:])] if col.startswith("u_")
                                           else r.y[row, r.axes.index(col)])
        assert got == v


@FAST
@given(st.binary(max_size=400) | st.text(max_size=400).map(lambda s: s.encode()))
def test_csv_random_bytes_give_a_value_error_naming_the_file(tmp_path_factory, blob):
    p = _tmp(tmp_path_factory, "g.csv")
    p.write_bytes(blob)
    with pytest.raises(ValueError) as ei:
        load_csv(p)
    assert str(p) in str(ei.value)


@FAST
@given(csv_runs(), st.sampled_from([1e-3, 1e3, 1e6]), st.sampled_from(["t", "u", "y"]))
def test_csv_unit_mistakes_are_refused_naming_the_column(tmp_path_factory, run, scale, which):
    cols, order, delim, axes = run
    cols = copy.deepcopy(cols)
    if which == "t":
        assume(scale > 1)  # a time column in ms/µs
        cols["t"] = cols["t"] * scale
    elif which == "u":
        for a in axes:
            cols[f"u_{a}"] = cols[f"u_{a}"] * (1e-3 if scale == 1e-3 else scale)  # kV / mV
    else:
        assume(scale > 1)
        for a in axes:
            cols[a] = cols[a] * scale * 1e2  # µm / mm written as m
    p = _tmp(tmp_path_factory, "u.csv")
    p.write_text(_csv_text(cols, order, delim))
    with pytest.raises(ValueError) as ei:
        load_csv(p)
    msg = str(ei.value)
    assert str(p) in msg and "column" in msg


# ---------------------------------------------------------------------------------------------------------------
# .mat

@FAST
@given(st.integers(2, 30), st.integers(1, 3), st.booleans(), st.booleans(),
       st.sampled_from(["ok", "drop_u", "drop_y", "short_y", "text_u", "nan", "3d"]))
def test_mat_any_shape_is_read_or_refused_naming_the_variable(tmp_path_factory, n, k, transpose_u, transpose_y, bad):
    import scipy.io

    rng = np.random.default_rng(n * 7 + k)
    t = np.arange(n) / 1000.0
    u = rng.uniform(-100, 100, (n, k))
    u[0, 0] = 100.0
    y = u * 1e-7
    d = {"t": t, "u": u.T if transpose_u else u, "y": y.T if transpose_y else y}
    if bad == "drop_u":
        del d["u"]
    elif bad == "drop_y":
        del d["y"]
    elif bad == "short_y":
        d["y"] = y[:-1]
    elif bad == "text_u":
        d["u"] = "volts"
    elif bad == "nan":
        d["y"] = y.copy()
        d["y"][n // 2, 0] = np.nan
    elif bad == "3d":
        d["u"] = u[:, :, None] if k > 0 else u
    p = _tmp(tmp_path_factory, "r.mat")
    scipy.io.savemat(p, d)
    try:
        r = load_mat(p)
    except ValueError as exc:
        assert str(p) in str(exc)
        assert bad != "ok" or (n == k and transpose_u != transpose_y), str(exc)  # square + mixed: ambiguous
        return
    if n == k:  # a square matrix cannot be told from its transpose: the file's orientation is taken
        return
    assert bad == "ok"
    assert np.array_equal(r.u, u) and np.array_equal(r.y, y) and np.array_equal(r.t, t)


# ---------------------------------------------------------------------------------------------------------------
# MCAP

FS, DT_NS, T0, NB = 20000, 50_000, 1_763_800_000_000_000_000, 100


def _record(path: Path, n_blocks: int, seed: int, chunk_size: int = 4096) -> dict:
    rng = np.random.default_rng(seed)
    sig = {r: rng.standard_normal((n_blocks * NB, 2)) * s for r, s in
           (("reference", 1e-6), ("voltage", 50.0), ("displacement", 1e-6))}
    with McapRecorder(path, chunk_size=chunk_size, flush_interval=None) as rec:
        rec.set_metadata({"sample_rate": FS, "t0_ns": T0, "axes": ["x", "y"]})
        for role in sig:
            rec.register_topic(f"/{role}", B.BLOCK_TYPE)
        for b in range(n_blocks):
            for role, arr in sig.items():
                rec.write(f"/{role}", B.serialize_block(arr[b * NB:(b + 1) * NB], T0 + b * NB * DT_NS), T0)
    return sig


@pytest.fixture(scope="module")
def good_mcap(tmp_path_factory):
    p = tmp_path_factory.mktemp("mcap") / "good.mcap"
    sig = _record(p, 40, seed=1)
    return p, p.read_bytes(), sig


def _check_read(path: Path, sig: dict) -> None:
    """An error naming the file, or every finite sample equal to the one written at the same run index."""
    try:
        run = read_run(path)
    except ValueError as exc:
        assert path.name in str(exc), str(exc)
        return
    k = np.rint(run.t * FS).astype(np.int64)  # run index (t0 = T0 from the metadata)
    assert k.min() >= 0 and k.max() < len(sig["voltage"])
    for arr, role in ((run.u, "voltage"), (run.y, "displacement"), (run.reference, "reference")):
        ok = ~np.isnan(arr).any(axis=1)
        assert np.array_equal(arr[ok], sig[role][k[ok]])
    if run.meta["truncated"]:
        assert run.meta["truncation_error"]


@_settings(40)
@given(st.floats(0.0, 1.0))
def test_mcap_cut_anywhere(tmp_path_factory, good_mcap, frac):
    _, data, sig = good_mcap
    p = _tmp(tmp_path_factory, "cut.mcap")
    p.write_bytes(data[: int(frac * len(data))])
    _check_read(p, sig)


def _data_section(data: bytes) -> tuple[int, int]:
    """Byte range of the chunks (first Chunk record … DataEnd), from the file's own framing."""
    import struct

    pos, first, end = 8, None, len(data)
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06 and first is None:
            first = pos
        if op == 0x0F:
            end = pos
            break
        pos += 9 + length
    return first, end


@_settings(40)
@given(st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), min_size=1, max_size=8))
def test_mcap_flipped_bytes_in_the_data_section(tmp_path_factory, good_mcap, flips):
    _, data, sig = good_mcap
    lo, hi = _data_section(data)
    buf = bytearray(data)
    for frac, mask in flips:
        buf[lo + int(frac * (hi - lo - 1))] ^= mask
    p = _tmp(tmp_path_factory, "flip.mcap")
    p.write_bytes(bytes(buf))
    _check_read(p, sig)


@FAST
@given(st.sampled_from(["std_msgs/msg/String", "sensor_msgs/msg/PointCloud2", "diagnostic_msgs/msg/DiagnosticArray"]),
       st.sampled_from(["wrong_type_field", "fields_yx", "int32", "big_endian", "short_data", "no_fields"]),
       st.integers(1, 5))
def test_mcap_foreign_messages_on_contract_topics(tmp_path_factory, type_name, flavour, n_blocks):
    """Another writer's messages on /voltage …: refused naming the file, or decoded by field name."""
    p = _tmp(tmp_path_factory, "foreign.mcap")
    rng = np.random.default_rng(n_blocks)
    sig = {"voltage": rng.uniform(-100, 100, (n_blocks * NB, 2)), "displacement": rng.normal(0, 1e-6, (n_blocks * NB, 2))}
    sig["reference"] = sig["displacement"]
    with McapRecorder(p) as rec:
        rec.set_metadata({"sample_rate": FS, "t0_ns": T0})
        rec.register_topic("/displacement", B.BLOCK_TYPE)
        rec.register_topic("/voltage", type_name)
        for b in range(n_blocks):
            stamp = T0 + b * NB * DT_NS
            rec.write("/displacement", B.serialize_block(sig["displacement"][b * NB:(b + 1) * NB], stamp), T0)
            blk = sig["voltage"][b * NB:(b + 1) * NB]
            if type_name == "std_msgs/msg/String":
                raw = B.serialize_message({"data": json.dumps(blk.tolist())[:200]}, type_name)
            elif type_name == "diagnostic_msgs/msg/DiagnosticArray":
                raw = B.serialize_message({"header": {"stamp": B.ns_to_stamp(stamp), "frame_id": ""},
                                           "status": []}, type_name)
            else:
                m = B.encode_block(blk, stamp)
                if flavour == "fields_yx":
                    m = B.encode_block(blk[:, ::-1], stamp, axes=("y", "x"))
                elif flavour == "wrong_type_field":
                    m["fields"][0]["datatype"] = 7
                elif flavour == "int32":
                    m["fields"] = [dict(f, datatype=5) for f in m["fields"]]
                elif flavour == "big_endian":
                    m["is_bigendian"] = True
                elif flavour == "short_data":
                    m["data"] = m["data"][:-8]
                elif flavour == "no_fields":
                    m["fields"] = []
                raw = B.serialize_message(m, type_name)
            rec.write("/voltage", raw, T0)
    try:
        run = read_run(p)
    except ValueError as exc:
        assert p.name in str(exc)
        return
    ok = ~np.isnan(run.u).any(axis=1)
    if ok.any():
        assert type_name == B.BLOCK_TYPE and flavour == "fields_yx"
        assert np.array_equal(run.u[ok], sig["voltage"][:len(run)][ok])  # by name: x is x
    else:
        assert run.meta["blocks"].get("voltage", {"count": 0})["count"] == 0 or \
            run.meta["blocks"]["voltage"]["malformed"] > 0
    assert np.array_equal(run.y, sig["displacement"][:len(run)])


# ---------------------------------------------------------------------------------------------------------------
# block messages

@FAST
@given(st.integers(1, 50), st.lists(st.sampled_from(AXES_POOL), min_size=1, max_size=4, unique=True), st.data())
def test_block_round_trip_by_name_any_field_order(n, axes, data):
    rng = np.random.default_rng(n)
    blk = rng.standard_normal((n, len(axes)))
    stamp = data.draw(st.integers(0, 2**31 * 10**9 - 1))
    perm = data.draw(st.permutations(range(len(axes))))
    wire = B.serialize_block(blk[:, perm], stamp, axes=[axes[i] for i in perm])
    s, back, names = B.deserialize_block(wire, axes)
    assert s == stamp and names == tuple(axes) and np.array_equal(back, blk)


BLOCK_MUTATIONS = {
    "datatype": lambda m, rnd: m["fields"][0].__setitem__("datatype", rnd.choice([1, 2, 3, 4, 5, 6, 7])),
    "count": lambda m, rnd: m["fields"][0].__setitem__("count", rnd.choice([0, 2, 3])),
    "offset": lambda m, rnd: m["fields"][-1].__setitem__("offset", rnd.choice([1, 3, 4, 1000])),
    "point_step": lambda m, rnd: m.__setitem__("point_step", rnd.choice([0, 4, 7, 1])),
    "row_step": lambda m, rnd: m.__setitem__("row_step", m["row_step"] + rnd.choice([-8, 8, 1])),
    "data": lambda m, rnd: m.__setitem__("data", m["data"][:-rnd.choice([1, 8, 9])]),
    "is_bigendian": lambda m, rnd: m.__setitem__("is_bigendian", True),
    "height": lambda m, rnd: m.__setitem__("height", rnd.choice([0, 2, 3])),
    "fields": lambda m, rnd: m.__setitem__("fields", []),
}


@FAST
@given(st.integers(1, 20), st.sampled_from(sorted(BLOCK_MUTATIONS)), st.randoms(use_true_random=False))
def test_block_contract_violations_name_the_field(n, what, rnd):
    m = B.encode_block(np.ones((n, 2)), 0)
    BLOCK_MUTATIONS[what](m, rnd)
    with pytest.raises(ValueError, match=r"^block"):
        B.decode_block(m, ("x", "y"))
    # on the wire too (CDR), through the same decoder
    with pytest.raises(ValueError):
        B.deserialize_block(B.serialize_message(m, B.BLOCK_TYPE), ("x", "y"))


@FAST
@given(st.binary(max_size=300))
def test_block_random_bytes_are_a_value_error(blob):
    with pytest.raises(ValueError):
        B.deserialize_block(blob)


# ---------------------------------------------------------------------------------------------------------------
# YAML configs

PAPER_DICT = yaml.safe_load(PAPER.read_text())
SCALARS = {"sample_rate", "vibration.t_r", "vibration.eps_s", "vibration.k_o", "vibration.gamma_max",
           "vibration.order", "limits.voltage", "limits.slew", "limits.stale_timeout", "limits.safe_voltage"}


def _leaf_paths(d, prefix=()):
    for k, v in d.items():
        if k == "variants":
            continue
        if isinstance(v, dict):
            yield from _leaf_paths(v, prefix + (k,))
        else:
            yield prefix + (k,)


LEAVES = sorted(_leaf_paths(PAPER_DICT))
VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                   st.lists(st.floats(-1e3, 1e3), max_size=5), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                                 max_size=2))


def _load_dict(tmp_path_factory, d) -> PiezoConfig:
    p = _tmp(tmp_path_factory, "c.yaml")
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return load_config(p)


@_settings(50)
@given(st.sampled_from(LEAVES), VALUES)
def test_config_random_leaf_value(tmp_path_factory, path, value):
    d = copy.deepcopy(PAPER_DICT)
    sec = d
    for k in path[:-1]:
        sec = sec[k]
    sec[path[-1]] = value
    try:
        cfg = _load_dict(tmp_path_factory, d)
    except ConfigError as exc:
        # names the field, or a field of the same section (a value can break a section-level check)
        assert exc.field.split(".")[0] in (path[0], "config") or str(PAPER.name) in exc.field or exc.field.endswith(
            ".yaml"), (path, value, str(exc))
        return
    name = ".".join(path)
    if name in SCALARS:  # a scalar that loads, loads exactly as given: no rounding, no silent default
        got = cfg.sample_rate if name == "sample_rate" else getattr(getattr(cfg, path[0]), path[1])
        assert got == float(value), (name, value, got)


@FAST
@given(st.sampled_from(LEAVES), st.sampled_from(["drop", "misspell", "upper"]))
def test_config_missing_or_misspelled_key(tmp_path_factory, path, how):
    d = copy.deepcopy(PAPER_DICT)
    sec = d
    for k in path[:-1]:
        sec = sec[k]
    v = sec.pop(path[-1])
    if how == "misspell":
        sec[path[-1] + "_"] = v
    elif how == "upper":
        assume(path[-1].upper() != path[-1])
        sec[path[-1].upper()] = v
    try:
        cfg = _load_dict(tmp_path_factory, d)
    except ConfigError as exc:
        head = exc.field.split(".")[0]
        assert head.rstrip("_").lower() == path[0].lower() or head in ("axes", "sample_rate") \
            or ".".join(path) in str(exc), (path, str(exc))  # e.g. no units.length: "Dp … check units.length"
        if how != "drop":
            assert "unknown key" in str(exc) or "missing" in str(exc), str(exc)
        return
    # loading without the key is fine only where a documented default exists (and misspellings never load)
    assert how == "drop", (path, how)
    assert isinstance(cfg, PiezoConfig)


# ---------------------------------------------------------------------------------------------------------------
# runtime parameters (they go through the same validation)

@pytest.fixture(scope="module")
def base_cfg():
    return load_config(PAPER)


@_settings(40)
@given(st.data())
def test_runtime_parameters_are_validated_naming_the_parameter(base_cfg, data):
    from piezo_ff_ros.core.param_map import config_to_params, params_to_config

    params = config_to_params(base_cfg)
    name = data.draw(st.sampled_from(sorted(k for k in params if not k.endswith(("_deg", ".num", ".den")))))
    cur = params[name]
    if isinstance(cur, bool):
        value = data.draw(st.one_of(st.booleans(), st.integers(), st.text(max_size=4)))
    elif isinstance(cur, (list, tuple)):
        scale = data.draw(st.sampled_from([1.0, -1.0, 1e7, 1e-7, 0.0, float("nan")]))
        value = [float(v) * scale for v in cur] if data.draw(st.booleans()) else \
            data.draw(st.lists(st.floats(-1e3, 1e3), max_size=6))
    else:
        value = data.draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**9, 10**9),
                                    st.text(max_size=4), st.booleans()))
    try:
        cfg = params_to_config({name: value}, base_cfg)
    except ConfigError as exc:
        root = name.split(".")[0]
        assert exc.field.split(".")[0] in (root, "config"), (name, value, str(exc))
        return
    assert isinstance(cfg, PiezoConfig)


@_settings(40)
@given(st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), min_size=1, max_size=6))
def test_mcap_flipped_bytes_anywhere_never_crash(tmp_path_factory, good_mcap, flips):
    """Anywhere in the file (header, metadata, summary, footer too): a ValueError naming the file or a run."""
    _, data, sig = good_mcap
    buf = bytearray(data)
    for frac, mask in flips:
        buf[int(frac * (len(buf) - 1))] ^= mask
    p = _tmp(tmp_path_factory, "any.mcap")
    p.write_bytes(bytes(buf))
    try:
        run = read_run(p)
    except ValueError as exc:
        assert p.name in str(exc), str(exc)
    else:
        assert run.u.shape == run.y.shape and len(run.t) == len(run.u)


@_settings(25)
@given(st.floats(0.3, 1.0), st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), max_size=3))
def test_recover_output_opens_strictly_and_keeps_every_readable_sample(tmp_path_factory, good_mcap, cut, flips):
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    from piezo_ff_ros.core.recording.recover import recover_mcap

    _, data, sig = good_mcap
    lo, hi = _data_section(data)
    buf = bytearray(data)
    for frac, mask in flips:
        buf[lo + int(frac * (hi - lo - 1))] ^= mask
    d = tmp_path_factory.mktemp("rec")
    src, dst = d / "in.mcap", d / "out.mcap"
    src.write_bytes(bytes(buf[: int(cut * len(buf))]))
    try:
        report = recover_mcap(src, dst)
    except ValueError as exc:
        assert src.name in str(exc)
        return
    with open(dst, "rb") as f:
        n_mcap = sum(1 for _ in make_reader(f).iter_messages())
    with AnyReader([dst]) as r:
        n_rosbags = sum(1 for _ in r.messages())
    assert n_mcap == n_rosbags == report["messages_written"]
    if report["messages_written"]:
        try:
            a = read_run(src)
        except ValueError:
            return
        b = read_run(dst)
        assert np.array_equal(a.u, b.u, equal_nan=True) and np.array_equal(a.y, b.y, equal_nan=True)


JSONISH = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True),
                    st.text(max_size=10), st.lists(st.one_of(st.text(max_size=3), st.integers()), max_size=3))


@_settings(40)
@given(st.dictionaries(st.sampled_from(["axes", "sample_rate", "t0_ns", "block_size"]),
                      JSONISH | st.sampled_from([10000, 25000, 40000, 20000.0, '["y", "x"]', "y,x"]), max_size=4))
def test_mcap_any_metadata_values(tmp_path_factory, md):
    """Whatever another writer puts in the metadata record: an error naming the file, or the samples written."""
    p = _tmp(tmp_path_factory, "md.mcap")
    rng = np.random.default_rng(0)
    sig = {r: rng.standard_normal((4 * NB, 2)) for r in ("reference", "voltage", "displacement")}
    with McapRecorder(p) as rec:
        rec.set_metadata(md)
        for r in sig:
            rec.register_topic(f"/{r}", B.BLOCK_TYPE)
        for b in range(4):
            for r, arr in sig.items():
                rec.write(f"/{r}", B.serialize_block(arr[b * NB:(b + 1) * NB], T0 + b * NB * DT_NS), T0)
    try:
        run = read_run(p)
    except ValueError as exc:
        assert p.name in str(exc), str(exc)
        return
    assert run.axes == ("x", "y") and len(run) == 4 * NB
    for arr, r in ((run.u, "voltage"), (run.y, "displacement"), (run.reference, "reference")):
        assert np.array_equal(arr, sig[r])
