"""``piezo-ff play``: a voltage table played on the simulator (streamed through the driver core) and on a PI
controller (its wave generator and data recorder, through pipython's PISocket to the GCS 2.0 emulator on a loopback
TCP port); the run is what ``analyze``/``identify`` read, and the output starts and ends at the safe voltage by
ramps no steeper than the safe ramp."""
import json

import numpy as np
import pytest

from piezo_ff_ros.cli import main
from piezo_ff_ros.core.recording import load_run

FS = 20000.0


def write_table(path, n=4000, amp=(40.0, 20.0), offset=(40.0, 0.0)):
    t = np.arange(n) / FS
    u = np.column_stack([offset[0] + amp[0] * np.sin(2 * np.pi * 10 * t), offset[1] + amp[1] * np.cos(2 * np.pi * 10 * t)])
    np.savetxt(path, np.column_stack([t, u]), delimiter=",", header="t,u_x,u_y", comments="", fmt="%.17g")
    return u


@pytest.mark.parametrize("ext, mode", [(".csv", "lockstep"), (".mcap", "lockstep"), (".csv", "clocked")])
def test_play_on_the_simulator_records_applied_and_sensor_on_one_grid(tmp_path, capsys, ext, mode):
    u = write_table(tmp_path / "u.csv")
    out, js = tmp_path / f"run{ext}", tmp_path / "s.json"
    assert main(["play", str(tmp_path / "u.csv"), "--backend", "sim", "--param", f"mode={mode}", "--out", str(out),
                 "--json", str(js)]) == 0
    run = load_run(out)
    assert run.axes == ("x", "y") and len(run) == u.shape[0]
    np.testing.assert_allclose(run.sample_rate, FS)
    np.testing.assert_allclose(run.u, u, atol=1e-9)
    assert np.isfinite(run.y).all() and np.ptp(run.y[:, 0]) > 1e-7          # the stage moved, in metres
    s = json.loads(js.read_text())
    assert s["ramp_in_samples"] >= 1000 and s["ramp_out_samples"] >= 1000    # 50 ms at least
    # the safe ramp moves at most 1e4 V/s (0.5 V per sample) in and out; the table's own steps are smaller
    assert s["max_step_v"] <= 0.5 + 1e-9
    if ext == ".csv":      # load_run is what identify/diagnose read a CSV run with
        assert (tmp_path / "run.csv").read_text().split("\n", 1)[0] == "t,u_x,u_y,x,y"
    else:
        assert main(["analyze", str(out)]) == 0, capsys.readouterr().err


def test_play_refuses_a_table_that_does_not_fit_with_one_line(tmp_path, capsys):
    np.savetxt(tmp_path / "u.csv", np.zeros((10, 3)), delimiter=",", header="t,u_x,u_z", comments="")
    assert main(["play", str(tmp_path / "u.csv"), "--backend", "sim", "--out", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "u_y" in err, err
    assert not (tmp_path / "r.csv").exists()


pipython = pytest.importorskip("pipython")


def test_play_on_a_pi_controller_through_its_wave_generator(tmp_path, capsys):
    from gcs_emulator import GCSEmulator, GCSServer

    u = write_table(tmp_path / "u.csv", n=2000)
    emu = GCSEmulator(plant=lambda v: 0.1 * v, output=[2.0, 0.0])
    with GCSServer(emu) as srv:
        out = tmp_path / "run.csv"
        assert main(["play", str(tmp_path / "u.csv"), "--backend", "pi_gcs", "--param", "address=127.0.0.1",
                     "--param", f"port={srv.port}", "--param", "servo_rate=20000.0", "--param", "timeout_ms=1000",
                     "--out", str(out)]) == 0, capsys.readouterr().err
        run = load_run(out)
        np.testing.assert_allclose(run.u, u)
        np.testing.assert_allclose(run.y, 0.1 * u * 1e-6, rtol=1e-6)
        t, v = emu.output_events()
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        dv = np.abs(np.diff(np.vstack([[2.0, 0.0], v]), axis=0)).max(axis=1)
        assert dv.max() <= 1.0 + 1e-9                          # ramp in, table, ramp out: never more than 1 V
        assert [c for c in emu.log if c.startswith("WGO")][-1].endswith("0 2 0")   # generators stopped


def test_play_on_a_pi_controller_refuses_a_table_beyond_its_range(tmp_path, capsys):
    from gcs_emulator import GCSEmulator, GCSServer

    write_table(tmp_path / "u.csv", n=500, amp=(60.0, 10.0), offset=(60.0, 0.0))       # up to 120 V
    with GCSServer(GCSEmulator(vmin=-20.0, vmax=100.0)) as srv:
        assert main(["play", str(tmp_path / "u.csv"), "--backend", "pi_gcs", "--param", "address=127.0.0.1",
                     "--param", f"port={srv.port}", "--param", "servo_rate=20000.0",
                     "--out", str(tmp_path / "r.csv")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "outside the controller's range [-20, 100]" in err, err
        assert not any(c.startswith(("WAV", "SVA", "WGO")) for c in srv.emu.log)
