"""Bad-input benchmark (script, not a test): a catalogue of hostile CLI inputs, and how each one is answered.

    PYTHONPATH=. .venv/bin/python bench/bench_bad_inputs.py [--json F] [--verbose] [--subprocess]

Every case is a ``piezo-ff`` command line on a bad file, option or config (built here in a temp dir) with the
answer it must give:

- ``refuse``: exit code ≠ 0 and exactly one error line on stderr (``piezo-ff CMD: error: …``, or argparse's
  usage + error for a malformed option; progress lines may precede it) naming what is wrong (each case lists
  words the line must contain);
- ``warn``: the input is usable (a corrupt chunk, an outlier stamp, a killed recorder's file): exit code 0 and a
  warning naming the problem in the output.

Each answer is classified as **clear** (as expected), **traceback** (a Python traceback, or the CLI's "internal
error" line for an unexpected exception), **silently wrong** (exit 0 where a refusal was due, or no warning), or
**unclear** (refused, but not on one line or without naming the field).  Prints the counts per category and in
total; exit code 1 if any answer is not clear.  Cases run in-process through ``piezo_ff_ros.cli.main`` (the same
error handling as the console script); ``--subprocess`` runs each in a fresh ``python -m piezo_ff_ros``.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "pt230_94.yaml"


@dataclass
class Case:
    category: str
    name: str
    argv: list
    expect: str = "refuse"               # "refuse" or "warn"
    words: tuple = field(default=())     # must appear in the error / warning (case-insensitive)


# ----------------------------------------------------------------------------------------------------------------
# fixtures: bad files

def _csv(path: Path, header: str, rows) -> str:
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return str(path)


def _write(path: Path, content: bytes) -> str:
    path.write_bytes(content)
    return str(path)


def _good_rows(n=400, fs=20000.0, u_scale=1.0, t_scale=1.0, y_scale=1.0):
    t = np.arange(n) / fs
    u = np.column_stack([100 * np.sin(2 * np.pi * 50 * t), 60 * np.cos(2 * np.pi * 30 * t)])
    y = u * 1.7e-7
    return np.column_stack([t * t_scale, u * u_scale, y * y_scale]).tolist()


def _mcap(path: Path, *, n_blocks=20, stamp_of=None, close=True, metadata=True, axes=("x", "y"),
          topics=("reference", "voltage", "displacement"), chunk_size=8192) -> str:
    from piezo_ff_ros.core.recording import blocks as B
    from piezo_ff_ros.core.recording.mcap_io import McapRecorder

    fs, dt, t0, nb = 20000, 50_000, 1_763_800_000_000_000_000, 200
    rng = np.random.default_rng(0)
    rec = McapRecorder(path, chunk_size=chunk_size, flush_interval=None)
    if metadata:
        rec.set_metadata({"sample_rate": fs, "t0_ns": t0, "axes": list(axes)})
    for r in topics:
        rec.register_topic(f"/{r}", B.BLOCK_TYPE)
    for b in range(n_blocks):
        for r in topics:
            stamp = t0 + b * nb * dt
            if stamp_of is not None and stamp_of(r, b) is not None:
                stamp = stamp_of(r, b)
            scale = 50.0 if r == "voltage" else 1e-6
            rec.write(f"/{r}", B.serialize_block(rng.standard_normal((nb, len(axes))) * scale, stamp, axes), t0)
    if close:
        rec.close()
    else:
        rec.flush()
    return str(path)


def _chunks(data: bytes):
    import struct

    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            out.append((pos, 9 + length))
        if op == 0x0F:
            break
        pos += 9 + length
    return out


def _cfg(tmp: Path, name: str, edit) -> str:
    d = yaml.safe_load(PAPER.read_text())
    edit(d)
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return str(p)


def _set(path: str, value):
    def edit(d):
        keys = path.split(".")
        cur = d
        for k in keys[:-1]:
            cur = cur[k]
        cur[keys[-1]] = value
    return edit


def _drop(path: str):
    def edit(d):
        keys = path.split(".")
        cur = d
        for k in keys[:-1]:
            cur = cur[k]
        del cur[keys[-1]]
    return edit


def catalogue(tmp: Path) -> list[Case]:
    cases: list[Case] = []
    add = lambda *a, **k: cases.append(Case(*a, **k))  # noqa: E731
    adir = tmp / "a_directory"
    adir.mkdir()
    afile = tmp / "a_file.txt"
    afile.write_text("x")
    good_csv = _csv(tmp / "good.csv", "t,u_x,u_y,x,y", _good_rows())
    good_mcap = _mcap(tmp / "good.mcap")

    # ---- CSV files, through diagnose --data and identify --data (the two CSV readers' users)
    H = "t,u_x,u_y,x,y"
    rows = _good_rows()
    csv_cases = {
        "volts_in_kV": (_csv(tmp / "kv.csv", H, _good_rows(u_scale=1e-3)), ("kV", "u_")),
        "volts_in_mV": (_csv(tmp / "mv.csv", H, _good_rows(u_scale=1e3)), ("mV", "u_")),
        "time_in_ms": (_csv(tmp / "ms.csv", H, _good_rows(t_scale=1e3)), ("'t'", "ms")),
        "time_in_us": (_csv(tmp / "us.csv", H, _good_rows(t_scale=1e6)), ("'t'", "µs")),
        "displacement_in_um": (_csv(tmp / "um.csv", H, _good_rows(y_scale=1e6)), ("µm",)),
        "displacement_in_mm": (_csv(tmp / "mm.csv", H, _good_rows(y_scale=1e3)), ("mm",)),
        "nan_cell": (_csv(tmp / "nan.csv", H, [r if i != 7 else [r[0], "nan", *r[2:]] for i, r in enumerate(rows)]),
                     ("NaN", "row 9")),
        "text_cell": (_csv(tmp / "txt.csv", H, [r if i != 3 else [r[0], r[1], "abc", *r[3:]]
                                                for i, r in enumerate(rows)]), ("row 5", "not a number")),
        "missing_column": (_csv(tmp / "miss.csv", "t,u_x,u_y,x", [r[:4] for r in rows]), ("missing", "'y'")),
        "duplicate_column": (_csv(tmp / "dup.csv", "t,u_x,u_y,x,x", rows), ("duplicate",)),
        "unknown_column": (_csv(tmp / "unk.csv", "t,u_x,u_y,x,y,temp", [r + [20] for r in rows]), ("unknown", "temp")),
        "no_time_column": (_csv(tmp / "not.csv", "time,u_x,u_y,x,y", rows), ("missing column 't'",)),
        "no_input_column": (_csv(tmp / "noin.csv", "t,x,y", [[r[0], r[3], r[4]] for r in rows]), ("u_",)),
        "partial_reference": (_csv(tmp / "pref.csv", "t,u_x,u_y,x,y,r_x", [r + [0.0] for r in rows]), ("r_y",)),
        "short_row": (_csv(tmp / "short.csv", H, [r if i != 10 else r[:3] for i, r in enumerate(rows)]),
                      ("row 12",)),
        "time_not_increasing": (_csv(tmp / "dec.csv", H, [r if i != 20 else [rows[5][0], *r[1:]]
                                                          for i, r in enumerate(rows)]), ("does not increase",)),
        "non_uniform_time": (_csv(tmp / "nonu.csv", H, [r if i != 20 else [r[0] + 2e-5, *r[1:]]
                                                        for i, r in enumerate(rows)]), ("non-uniform",)),
        "header_only": (_csv(tmp / "hdr.csv", H, []), ("no data rows",)),
        "one_row": (_csv(tmp / "one.csv", H, rows[:1]), ("only 1 sample",)),
        "empty_file": (_write(tmp / "empty.csv", b""), ("empty",)),
        "binary_garbage": (_write(tmp / "bin.csv", os.urandom(2000)), ("bin.csv",)),
        "inf_cell": (_csv(tmp / "inf.csv", H, [r if i != 2 else [r[0], "inf", *r[2:]] for i, r in enumerate(rows)]),
                     ("Inf", "row 4")),
        "u_without_output": (_csv(tmp / "uz.csv", "t,u_x,u_y,u_z,x,y", [r[:3] + [1.0] + r[3:] for r in rows]),
                             ("'z'",)),
        "directory_named_csv": (str((tmp / "dir.csv").mkdir() or tmp / "dir.csv"), ("dir.csv",)),
        "missing_file": (str(tmp / "nope.csv"), ("nope.csv",)),
    }
    for name, (path, words) in csv_cases.items():
        add("csv", f"diagnose:{name}", ["diagnose", "--data", path, "--quiet"], words=words)
        add("csv", f"identify:{name}", ["identify", "--data", path, "--stage", "hysteresis", "--out",
                                        str(tmp / f"id_{name}.yaml"), "--no-hinf", "--quiet"], words=words)

    # ---- .mat files
    import scipy.io

    t = np.arange(400) / 20000.0
    u = np.column_stack([100 * np.sin(300 * t), 50 * np.cos(200 * t)])
    mats = {
        "missing_y": ({"t": t, "u": u}, ("missing", "'y'")),
        "text_u": ({"t": t, "u": "volts", "y": u * 1e-7}, ("'u'",)),
        "shape_mismatch": ({"t": t, "u": u, "y": u[:-3] * 1e-7}, ("'y'", "shape")),
        "nan_in_y": ({"t": t, "u": u, "y": np.where(np.arange(400)[:, None] == 5, np.nan, u * 1e-7)}, ("NaN",)),
        "volts_in_kV": ({"t": t, "u": u / 1000, "y": u * 1e-7}, ("kV",)),
        "time_in_ms": ({"t": t * 1000, "u": u, "y": u * 1e-7}, ("'t'", "ms")),
        "um_output": ({"t": t, "u": u, "y": u * 0.1}, ("µm",)),
        "in_out_count": ({"t": t, "u": u, "y": u[:, :1] * 1e-7}, ("input(s)",)),
        "bad_axes": ({"t": t, "u": u, "y": u * 1e-7, "axes": np.array(["x", "x"], dtype=object)}, ("'axes'",)),
    }
    for name, (d, words) in mats.items():
        p = tmp / f"{name}.mat"
        scipy.io.savemat(p, d)
        add("mat", f"diagnose:{name}", ["diagnose", "--data", str(p), "--quiet"], words=words)
    p = tmp / "garbage.mat"
    p.write_bytes(os.urandom(3000))
    add("mat", "diagnose:garbage", ["diagnose", "--data", str(p), "--quiet"], words=("garbage.mat",))
    p = tmp / "hdf5.mat"
    p.write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon" + b"\x00" * 200 + b"\x89HDF\r\n\x1a\n"
                  + os.urandom(500))
    add("mat", "diagnose:v7.3_or_corrupt", ["diagnose", "--data", str(p), "--quiet"], words=("hdf5.mat",))
    add("mat", "unknown_suffix", ["diagnose", "--data", str(afile), "--quiet"], words=("unknown format",))

    # ---- MCAP recordings, through analyze (and diagnose/identify for a few)
    data = Path(good_mcap).read_bytes()
    ch = _chunks(data)
    p = tmp / "empty.mcap"
    p.write_bytes(b"")
    add("mcap", "empty_file", ["analyze", str(p)], words=("empty.mcap",))
    p = tmp / "text.mcap"
    p.write_text("not an mcap at all")
    add("mcap", "not_mcap", ["analyze", str(p)], words=("not an MCAP",))
    p = tmp / "magic.mcap"
    p.write_bytes(b"\x89MCAP0\r\n" + os.urandom(3000))
    add("mcap", "magic_then_random", ["analyze", str(p)], words=("magic.mcap",))
    p = tmp / "header_only.mcap"
    p.write_bytes(data[:60])
    add("mcap", "header_only", ["analyze", str(p)], words=("header_only.mcap",))
    p = tmp / "half.mcap"
    p.write_bytes(data[: len(data) // 2])
    add("mcap", "cut_in_half", ["analyze", str(p)], expect="warn", words=("ends early",))
    p = tmp / "killed.mcap"
    _mcap(p, close=False)
    add("mcap", "killed_recorder", ["analyze", str(p)], expect="warn", words=("no footer",))
    buf = bytearray(data)
    off, ln = ch[len(ch) // 2]
    for i in range(off + 60, off + ln - 10, 101):
        buf[i] ^= 0xFF
    p = tmp / "corrupt_chunk.mcap"
    p.write_bytes(bytes(buf))
    add("mcap", "corrupt_chunk", ["analyze", str(p)], expect="warn", words=("corrupt", "chunk"))
    buf = bytearray(data)
    off, _ = ch[2]
    buf[off + 1:off + 9] = (2**60).to_bytes(8, "little")
    p = tmp / "bad_framing.mcap"
    p.write_bytes(bytes(buf))
    add("mcap", "damaged_record_length", ["analyze", str(p)], expect="warn", words=("chunk",))
    for name, stamp in (("outlier_stamp_future", 1_763_800_000_000_000_000 + 3 * 10**17),
                        ("outlier_stamp_zero", 0), ("outlier_stamp_max", (2**31 - 1) * 10**9)):
        p = tmp / f"{name}.mcap"
        _mcap(p, stamp_of=lambda r, b, _s=stamp: _s if (r, b) == ("voltage", 7) else None)
        add("mcap", name, ["analyze", str(p)], expect="warn", words=("outside the recording's span",))
    p = tmp / "offgrid.mcap"
    _mcap(p, stamp_of=lambda r, b: 1_763_800_000_000_000_000 + b * 200 * 50_000 + 7 if r == "displacement" else None)
    add("mcap", "off_grid_stamps", ["analyze", str(p)], expect="warn", words=("off the",))
    p = tmp / "no_blocks.mcap"
    _mcap(p, topics=())
    add("mcap", "no_block_topic", ["analyze", str(p)], words=("no block topic",))
    p = tmp / "no_metadata_one_block.mcap"
    _mcap(p, metadata=False, n_blocks=1)
    add("mcap", "no_rate_one_block", ["analyze", str(p)], words=("sample rate",))
    add("mcap", "sample_rate_30kHz", ["analyze", good_mcap, "--sample-rate", "30000"], words=("sample_rate",))
    add("mcap", "sample_rate_negative", ["analyze", good_mcap, "--sample-rate", "-5"], words=("sample_rate",))
    add("mcap", "sample_rate_nan", ["analyze", good_mcap, "--sample-rate", "nan"], words=("sample_rate",))
    add("mcap", "sample_rate_text", ["analyze", good_mcap, "--sample-rate", "fast"], words=("--sample-rate",))
    add("mcap", "missing_file", ["analyze", str(tmp / "nope.mcap")], words=("nope.mcap",))
    add("mcap", "namespace_absent", ["analyze", good_mcap, "--namespace", "tube9"], words=("no block topic",))
    bag = tmp / "bag_dir"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {relative_file_paths: [missing.mcap]}\n")
    add("mcap", "rosbag2_missing_storage", ["analyze", str(bag)], words=("missing",))
    bag2 = tmp / "bag_dir2"
    bag2.mkdir()
    (bag2 / "metadata.yaml").write_text(": : not yaml [")
    add("mcap", "rosbag2_bad_metadata", ["analyze", str(bag2)], words=("metadata",))
    add("mcap", "empty_directory", ["analyze", str(adir)], words=("a_directory",))
    add("mcap", "diagnose_on_garbage_mcap", ["diagnose", "--data", str(tmp / "magic.mcap"), "--quiet"],
        words=("magic.mcap",))

    # ---- output paths (item 6)
    add("output", "analyze_json_dir", ["analyze", good_mcap, "--json", str(adir)], words=("--json", "directory"))
    add("output", "analyze_plots_file", ["analyze", good_mcap, "--plots", str(afile)], words=("--plots",))
    add("output", "analyze_json_under_file", ["analyze", good_mcap, "--json", str(afile / "x.json")],
        words=("--json", "not a directory"))
    add("output", "diagnose_json_dir", ["diagnose", "--data", good_csv, "--json", str(adir)],
        words=("--json", "directory"))
    add("output", "diagnose_report_file", ["diagnose", "--data", good_csv, "--report", str(afile)],
        words=("--report",))
    add("output", "diagnose_apply_dir", ["diagnose", "--data", good_csv, "--apply", str(adir)], words=("--apply",))
    add("output", "check_json_dir", ["check", "--no-synthesis", "--json", str(adir)], words=("--json", "directory"))
    add("output", "check_config_is_dir", ["check", str(adir)], words=("directory",))
    add("output", "demo_out_is_file", ["demo", "--out", str(afile)], words=("--out", "not a directory"))
    add("output", "reproduce_json_dir", ["reproduce", "--json", str(adir)], words=("--json", "directory"))
    add("output", "reproduce_plots_file", ["reproduce", "--plots", str(afile)], words=("--plots",))
    add("output", "bench_json_dir", ["bench", "--json", str(adir)], words=("--json", "directory"))
    add("output", "identify_json_dir", ["identify", "--data", good_csv, "--out", str(tmp / "o.yaml"), "--json",
                                        str(adir)], words=("--json",))
    add("output", "identify_out_dir", ["identify", "--data", good_csv, "--stage", "hysteresis", "--out", str(adir)],
        words=("--out", "directory"))
    add("output", "commission_out_file", ["commission", "--sim-only", "--out", str(afile)],
        words=("--out", "not a directory"))
    add("output", "recover_out_is_input", ["recover", good_mcap, "--out", good_mcap], words=("overwrite",))
    add("output", "recover_out_exists", ["recover", good_mcap, "--out", str(afile)], words=("exists",))
    add("output", "recover_garbage", ["recover", str(tmp / "magic.mcap")], words=("magic.mcap",))
    add("output", "recover_directory", ["recover", str(adir)], words=("directory",))

    # ---- options
    add("options", "reproduce_creep_negative", ["reproduce", "--creep-duration", "-1"], words=("--creep-duration",))
    add("options", "reproduce_creep_nan", ["reproduce", "--creep-duration", "nan"], words=("--creep-duration",))
    add("options", "reproduce_noise_negative", ["reproduce", "--noise-nm", "-3"], words=("--noise-nm",))
    add("options", "reproduce_unknown_variant", ["reproduce", "--variant", "nope"], words=("variant",))
    add("options", "reproduce_bad_truth", ["reproduce", "--truth", "other"], words=("--truth",))
    add("options", "demo_block_size_zero", ["demo", "--block-size", "0"], words=("--block-size",))
    add("options", "demo_window_zero", ["demo", "--window", "0"], words=("--window",))
    add("options", "demo_domain_id", ["demo", "--domain-id", "999"], words=("--domain-id",))
    add("options", "demo_voltage_limit", ["demo", "--voltage-limit", "-200"], words=("--voltage-limit",))
    add("options", "demo_unknown_experiment", ["demo", "--only", "nope", "--out", str(tmp / "demo_o")],
        words=("--only",))
    add("options", "diagnose_split", ["diagnose", "--data", good_csv, "--split", "2"], words=("--split",))
    add("options", "diagnose_data_and_train", ["diagnose", "--data", good_csv, "--train", good_csv],
        words=("--data",))
    add("options", "diagnose_nothing", ["diagnose"], words=("--train",))
    add("options", "identify_stage_count", ["identify", "--data", good_csv, good_csv, "--stage", "hysteresis",
                                            "--out", str(tmp / "o.yaml")], words=("--stage",))
    add("options", "unknown_command", ["frobnicate"], words=("invalid choice",))
    add("options", "check_unknown_variant", ["check", "--no-synthesis", "--variant", "nope"], words=("variant",))

    # ---- YAML configs, through check (and reproduce/demo for the infeasible one)
    cfgs = {
        "units_voltage_kV": (_set("units.voltage", "kV"), ("units.voltage",)),
        "units_length_furlong": (_set("units.length", "furlong"), ("units.length",)),
        "units_length_dropped": (_drop("units.length"), ("hysteresis.Dp",)),
        "misspelled_top": (lambda d: d.__setitem__("sample_rte", 20000), ("sample_rte", "sample_rate")),
        "misspelled_gamma_max": (lambda d: d["vibration"].__setitem__("gama_max", 1), ("gama_max",)),
        "misspelled_Gamma": (lambda d: d["hysteresis"].__setitem__("Gama", 1), ("Gama",)),
        "misspelled_limit": (lambda d: d["limits"].__setitem__("voltge", 1), ("voltge",)),
        "misspelled_tf_den": (lambda d: d["dynamics"]["G_L"]["xx"].__setitem__("dne", [[1, 1]]), ("dne",)),
        "order_12.5": (_set("vibration.order", 12.5), ("vibration.order",)),
        "order_text": (_set("vibration.order", "twelve"), ("vibration.order",)),
        "order_zero": (_set("vibration.order", 0), ("vibration.order",)),
        "sample_rate_30kHz": (_set("sample_rate", 30000.0), ("sample_rate",)),
        "sample_rate_zero": (_set("sample_rate", 0), ("sample_rate",)),
        "sample_rate_text": (_set("sample_rate", "fast"), ("sample_rate",)),
        "sample_rate_1mHz": (_set("sample_rate", 1e-3), ("sample_rate",)),
        "Dp_1e7_nominal": (_set("hysteresis.Dp", [[1.663e6, 0], [0, 1.803e6]]), ("hysteresis.Dp",)),
        "Dp_singular": (_set("hysteresis.Dp", [[0.1, 0.1], [0.1, 0.1]]), ("hysteresis.Dp",)),
        "Dp_nan": (_set("hysteresis.Dp", [[float("nan"), 0], [0, 0.18]]), ("hysteresis.Dp",)),
        "Dp_shape": (_set("hysteresis.Dp", [[0.1, 0, 0], [0, 0.1, 0]]), ("hysteresis.",)),
        "B_huge": (_set("hysteresis.B", [[73.0, 0], [0, 54.0]]), ("hysteresis.B",)),
        "K_singular": (_set("creep.K", [[1, 1], [1, 1]]), ("creep.K",)),
        "Cr_unstable": (_set("creep.Cr.xx.den", [[1, -0.1], [1, 0.01249]]), ("creep.Cr.xx",)),
        "Cr_improper": (_set("creep.Cr.xx.num", [[1, 2, 3, 4]]), ("creep.Cr.xx",)),
        "G_L_unknown_entry": (lambda d: d["dynamics"]["G_L"].__setitem__("xz", {"k": 1, "den": [[1, 1]]}),
                              ("dynamics.G_L.xz",)),
        "G_L_missing": (_drop("dynamics.G_L"), ("dynamics.G_L",)),
        "hysteresis_missing": (_drop("hysteresis"), ("hysteresis",)),
        "t_r_negative": (_set("vibration.t_r", -0.025), ("vibration.t_r",)),
        "eps_s_one": (_set("vibration.eps_s", 1.0), ("vibration.eps_s",)),
        "W2_length": (_set("vibration.W2", [1.0, 1.0, 1.0]), ("vibration.W2",)),
        "W2_bool": (_set("vibration.W2", True), ("vibration.W2",)),
        "cascade_order": (_set("cascade.order", "sideways"), ("cascade.order",)),
        "cascade_flag_text": (_set("cascade.creep", "yes please"), ("cascade.creep",)),
        "limits_voltage_1e9": (_set("limits.voltage", 1e9), ("limits.voltage",)),
        "limits_voltage_negative": (_set("limits.voltage", -200), ("limits.voltage",)),
        "limits_slew_zero": (_set("limits.slew", 0), ("limits.slew",)),
        "limits_stale_huge": (_set("limits.stale_timeout", 1e6), ("limits.stale_timeout",)),
        "safe_voltage_outside": (_set("limits.safe_voltage", 500), ("limits.safe_voltage",)),
        "safe_voltage_list": (_set("limits.safe_voltage", []), ("limits.safe_voltage",)),
        "axes_empty": (_set("axes", []), ("axes",)),
        "axes_duplicate": (_set("axes", ["x", "x"]), ("axes",)),
        "axes_string": (_set("axes", "xy"), ("axes",)),
        "limits_not_mapping": (_set("limits", [1, 2]), ("limits",)),
        "unknown_variant_selected": (_set("variant", "nope"), ("variant",)),
        "variant_bad_path": (_set("variants.gyx_gain_div10.set", {"dynamics.G_L.zz.k": 1}),
                             ("variants.gyx_gain_div10", "dynamics.G_L.zz.k")),
        "controller_unstable": (_set("vibration.controller", {"A": [[1.0]], "B": [[1, 1]], "C": [[1], [1]],
                                                              "D": [[0, 0], [0, 0]]}), ("vibration.controller",)),
        "hinf_infeasible": (_set("vibration.gamma_max", 0.5), ("infeasible", "gamma_max")),
    }
    for name, (edit, words) in cfgs.items():
        args = ["check", _cfg(tmp, name, edit)]
        if name != "hinf_infeasible":
            args.append("--no-synthesis")
        add("config", f"check:{name}", args, words=words)
    text = PAPER.read_text()
    for name, content, words in (
            ("duplicate_key", text.replace("  eps_s: 0.01\n", "  eps_s: 0.01\n  eps_s: 0.5\n"), ("duplicate key",)),
            ("not_yaml", "hysteresis: [unclosed\n", ("not valid YAML",)),
            ("top_level_list", "- 1\n- 2\n", ("mapping",)),
            ("empty", "", ("mapping",)),
            ("tabs", text.replace("  t_r: 0.025", "\tt_r: 0.025"), ("YAML",))):
        p = tmp / f"{name}.yaml"
        p.write_text(content)
        add("config", f"check:{name}", ["check", "--no-synthesis", str(p)], words=words)
    p = tmp / "binary.yaml"
    p.write_bytes(os.urandom(500) + b"\xff\xfe")
    add("config", "check:binary", ["check", "--no-synthesis", str(p)], words=("binary.yaml",))
    add("config", "check:missing_file", ["check", str(tmp / "nope.yaml")], words=("nope.yaml",))
    infeasible = _cfg(tmp, "hinf_infeasible", _set("vibration.gamma_max", 0.5))
    add("config", "reproduce:hinf_infeasible", ["reproduce", "--config", infeasible, "--quiet", "--no-robustness",
                                                "--creep-duration", "2"], words=("infeasible",))
    add("config", "demo:hinf_infeasible", ["demo", "--config", infeasible, "--quiet", "--out", str(tmp / "d")],
        words=("infeasible",))
    add("config", "reproduce:kV", ["reproduce", "--config", _cfg(tmp, "kv2", _set("units.voltage", "kV"))],
        words=("units.voltage",))
    add("config", "diagnose:bad_model", ["diagnose", "--model", _cfg(tmp, "o125", _set("vibration.order", 12.5)),
                                         "--data", good_csv], words=("vibration.order",))
    add("config", "identify:bad_base", ["identify", "--data", good_csv, "--stage", "hysteresis", "--base", str(adir),
                                        "--out", str(tmp / "o.yaml")], words=("directory",))
    return cases


# ----------------------------------------------------------------------------------------------------------------
# running and judging

def _run_inprocess(argv) -> tuple[int, str, str, str | None]:
    from piezo_ff_ros.cli import main

    out, err = io.StringIO(), io.StringIO()
    tb = None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code if isinstance(exc.code, int) else 2
        except BaseException:  # noqa: BLE001 - exactly what the benchmark looks for
            tb = traceback.format_exc()
            code = -1
    return code, out.getvalue(), err.getvalue(), tb


def _run_subprocess(argv) -> tuple[int, str, str, str | None]:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-m", "piezo_ff_ros", *argv], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=300)
    tb = proc.stderr if "Traceback (most recent call last)" in proc.stderr else None
    return proc.returncode, proc.stdout, proc.stderr, tb


def judge(case: Case, code: int, out: str, err: str, tb: str | None) -> tuple[str, str]:
    """(verdict, the line that decided it)."""
    if tb is not None or "Traceback (most recent call last)" in err or "internal error" in err:
        return "traceback", (tb or err).strip().splitlines()[-1][:200]
    text = err.strip()
    if case.expect == "warn":
        both = (out + "\n" + err).lower()
        if code != 0:
            return "unclear", f"exit {code}: {text[-200:]}"
        missing = [w for w in case.words if w.lower() not in both]
        return ("clear", next((ln for ln in (out + err).splitlines()
                               if case.words and case.words[0].lower() in ln.lower()), "")[:200]) if not missing \
            else ("silently wrong", f"exit 0 without a warning naming {missing}")
    if code == 0:
        return "silently wrong", f"exit 0: {(out.strip().splitlines() or [''])[-1][:200]}"
    # progress lines on stderr are fine; the answer is one error line (argparse: usage lines + one error line)
    lines = [ln for ln in text.splitlines() if ": error: " in ln]
    if len(lines) != 1:
        return "unclear", f"exit {code}, {len(lines)} error line(s): {text[-200:]}"
    line = lines[0]
    missing = [w for w in case.words if w.lower() not in line.lower()]
    if missing:
        return "unclear", f"does not name {missing}: {line[:200]}"
    return "clear", line[:240]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", metavar="FILE", help="write every case and its verdict as JSON")
    ap.add_argument("--verbose", action="store_true", help="print every case's answer")
    ap.add_argument("--subprocess", action="store_true", help="each case in a fresh python -m piezo_ff_ros")
    ap.add_argument("--only", metavar="CATEGORY", help="run one category (csv, mat, mcap, output, options, config)")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="bench_bad_inputs_roslog_"))
    run = _run_subprocess if args.subprocess else _run_inprocess
    t_start = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_bad_inputs_") as d:
        cases = catalogue(Path(d))
        if args.only:
            cases = [c for c in cases if c.category == args.only]
        for c in cases:
            t0 = time.perf_counter()
            code, out, err, tb = run(c.argv)
            verdict, line = judge(c, code, out, err, tb)
            results.append({"category": c.category, "name": c.name, "expect": c.expect, "exit_code": code,
                            "verdict": verdict, "answer": line, "seconds": round(time.perf_counter() - t0, 3)})
            if args.verbose or verdict != "clear":
                print(f"[{verdict:>14}] {c.category}/{c.name}: {line}", flush=True)
    verdicts = ("clear", "traceback", "silently wrong", "unclear")
    cats = sorted({r["category"] for r in results}, key=[c.category for c in cases].index)
    print(f"\n{'category':<10}{'tried':>7}{'refusals':>10}{'warnings':>10}" + "".join(f"{v:>16}" for v in verdicts))
    for cat in cats + ["total"]:
        rs = [r for r in results if cat in ("total", r["category"])]
        print(f"{cat:<10}{len(rs):>7}{sum(r['expect'] == 'refuse' for r in rs):>10}"
              f"{sum(r['expect'] == 'warn' for r in rs):>10}"
              + "".join(f"{sum(r['verdict'] == v for r in rs):>16}" for v in verdicts))
    tot = {v: sum(r["verdict"] == v for r in results) for v in verdicts}
    print(f"\nbad inputs tried {len(results)} / clear errors or warnings {tot['clear']} / tracebacks "
          f"{tot['traceback']} / silently wrong {tot['silently wrong']} / unclear {tot['unclear']}  "
          f"({time.perf_counter() - t_start:.1f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": {"tried": len(results), **tot}, "cases": results},
                                              indent=2) + "\n")
    return 0 if tot["clear"] == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
