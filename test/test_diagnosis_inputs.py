"""What `diagnose` takes in: inputs it cannot diagnose are refused with one line; the package's own recordings
(applied voltage, gaps between experiments, a held-out part that does not start at rest, one axis) go through."""
from __future__ import annotations

import json

import numpy as np
import pytest

from bench.synthetic.in_family import make_runs
from piezo_ff_ros.cli import main as cli_main
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording.mcap_io import McapRecorder
from piezo_ff_ros.core.recording.run import RunData

FS = 5000.0
FAST = ("gain_mismatch", "input_delay", "thermal_drift")
NULL = {"name": "null", "effect": "none", "params": {}, "seed": 0}


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


@pytest.fixture(scope="module")
def runs(cfg):
    return make_runs(cfg, NULL, duration=2.0)


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert ": error: " in err, err
    for n in needles:
        assert n in err, err
    return err


def _write_csv(path, run):
    cols = [f"u_{a}" for a in run.axes] + list(run.axes)
    np.savetxt(path, np.column_stack([run.t, run.u, run.y]), delimiter=",", header=",".join(["t", *cols]),
               comments="", fmt="%.12g")
    return path


# -- refusals ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("what", ["all_zero", "constant_u", "constant_y"])
def test_no_excitation_is_refused_not_a_confident_none(cfg, runs, what):
    train, test = runs
    if what == "all_zero":
        bad = RunData(test.t, np.zeros_like(test.u), np.zeros_like(test.y), test.axes)
    elif what == "constant_u":
        bad = RunData(test.t, np.full_like(test.u, 30.0), test.y, test.axes)
    else:
        bad = RunData(test.t, test.u, np.full_like(test.y, 1e-6), test.axes)
    with pytest.raises(ValueError, match="no excitation|constant"):
        diagnose(cfg, bad, bad, DiagnosisOptions(candidates=FAST))


def test_no_excitation_through_the_cli_is_one_line(cfg, runs, tmp_path, capsys):
    train, _ = runs
    zero = RunData(train.t, np.zeros_like(train.u), np.zeros_like(train.y), train.axes)
    path = _write_csv(tmp_path / "zero.csv", zero)
    assert cli_main(["diagnose", "--data", str(path), "--candidates", ",".join(FAST)]) == 2
    _one_line_error(capsys, "no excitation")


def test_displacement_in_micrometres_stored_as_metres_is_refused(cfg, runs):
    train, test = runs
    um = RunData(test.t, test.u, test.y * 1e6, test.axes)
    with pytest.raises(ValueError, match=r"scale.*1e\+?0?6|µm"):
        diagnose(cfg, RunData(train.t, train.u, train.y * 1e6, train.axes), um, DiagnosisOptions(candidates=FAST))


def _record(path, u, y, fs, *, metadata_rate=None, applied=None, gaps=(), markers=(), block=250, axes=("x", "y")):
    """An MCAP of the topic contract: ``voltage`` (commanded), optionally ``voltage_applied``, ``displacement``;
    ``gaps``: [start, stop) sample ranges with no block on any topic; ``markers``: {k0: experiment name}."""
    dt_ns = int(round(1e9 / fs))
    marks = dict(markers)
    with McapRecorder(path) as rec:
        rec.set_metadata({"sample_rate": metadata_rate or fs, "t0_ns": 0, "axes": list(axes)})
        topics = ["voltage", "displacement"] + (["voltage_applied"] if applied is not None else [])
        for t in topics:
            rec.register_topic(f"/{t}", B.BLOCK_TYPE)
        rec.register_topic("/experiment", "std_msgs/msg/String")
        for k0 in range(0, len(u), block):
            if any(a <= k0 < b for a, b in gaps):
                continue
            stamp = k0 * dt_ns
            if k0 in marks:
                rec.write("/experiment", B.serialize_message(
                    {"data": json.dumps({"k0": k0, "stages": [], "name": marks[k0]})}, "std_msgs/msg/String"), stamp)
            for t, sig in (("voltage", u), ("displacement", y), ("voltage_applied", applied)):
                if t in topics:
                    rec.write(f"/{t}", B.serialize_block(sig[k0:k0 + block], stamp, axes), stamp)
    return path


def test_mcap_whose_metadata_rate_disagrees_with_its_stamps_is_refused(runs, tmp_path, capsys):
    train, _ = runs
    path = _record(tmp_path / "rate.mcap", train.u, train.y, FS, metadata_rate=2 * FS)
    assert cli_main(["diagnose", "--data", str(path), "--candidates", ",".join(FAST)]) == 2
    _one_line_error(capsys, "sample rate", "10000", "5000")
