"""``piezo-ff rig-check``: end to end on the clocked simulator (and lockstep), a failing device, bad options."""
import json

import numpy as np
import pytest

from piezo_ff_ros.cli import main
from piezo_ff_ros.core.hardware.rig_check import markdown
from piezo_ff_ros.core.hardware import ClockedSim, DriverSettings
from piezo_ff_ros import backends
from piezo_ff_ros.backends.base import BackendSpec, Param, int_range


def test_rig_check_sim_clocked_passes_with_the_default_write_ahead(tmp_path, capsys):
    """The clocked simulator at the driver's default write-ahead: no underrun, every check ok (it fails otherwise)."""
    out, md = tmp_path / "rig.json", tmp_path / "rig.md"
    code = main(["rig-check", "--backend", "sim", "--duration", "2", "--json", str(out), "--md", str(md)])
    rep = json.loads(out.read_text())
    for key in ("ok", "sample_rate_hz", "latency_samples", "underruns", "safe_ramp_max_step_v"):
        assert key in rep
    assert code == 0 and rep["ok"] is True, rep
    assert rep["underruns"] == 0 and rep["underruns_total"] == 0
    assert rep["checks"]["write_ahead"]["write_ahead_samples"] == round(DriverSettings.write_ahead * 20000)
    assert abs(rep["sample_rate_hz"] / 20000.0 - 1) < 0.02
    assert rep["latency_samples"] == 2
    lat = rep["checks"]["latency"]
    assert lat["ok"] is True and lat["residual_samples"] >= 0 and set(lat["axes"]) == {"x", "y"}
    assert 0 < rep["safe_ramp_max_step_v"] <= 1.0e4 / 20000.0
    assert rep["checks"]["link"]["clocked"] is True
    assert rep["checks"]["slew_limit"]["target_reached"] is True
    assert "| safe_ramp | yes |" in md.read_text()


def test_rig_check_skips_what_does_not_apply(tmp_path, capsys):
    """No hardware clock (lockstep): sample clock and write-ahead skipped; no sensor: latency skipped; not FAIL."""
    out = tmp_path / "r.json"
    assert main(["rig-check", "--backend", "sim", "--param", "mode=lockstep", "--duration", "0.3",
                 "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["checks"]["sample_clock"]["ok"] is None and "clock" in rep["checks"]["sample_clock"]["skipped"]
    assert rep["checks"]["write_ahead"]["ok"] is None
    assert rep["checks"]["latency"]["ok"] is True
    assert main(["rig-check", "--backend", "sim", "--param", "sensor=false", "--duration", "0.3",
                 "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["ok"] and rep["checks"]["latency"]["ok"] is None and "sensor" in rep["checks"]["latency"]["skipped"]


def test_rig_check_lockstep_and_bad_backend_parameter(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["rig-check", "--backend", "sim", "--param", "mode=lockstep", "--duration", "0.5",
                 "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["ok"] and rep["latency_samples"] == 0 and rep["checks"]["link"]["clocked"] is False
    assert "| sample_clock | skipped: " in markdown(rep)
    assert main(["rig-check", "--backend", "sim", "--param", "fifo_depth=3", "--json", str(out)]) == 1
    rep = json.loads(out.read_text())
    assert not rep["ok"] and "sim.fifo_depth" in rep["checks"]["link"]["error"]


class _Disconnecting(ClockedSim):
    """A clocked device that goes away after a number of polls (a cable pulled mid-check)."""

    def __init__(self, *a, polls: int, **kw):
        super().__init__(*a, **kw)
        self._left = polls

    def poll(self):
        self._left -= 1
        if self._left == 0:
            self.inject("disconnect")
        super().poll()


FLAKY = BackendSpec("flaky", "test device", {"polls": Param(50, "polls before disconnect", int_range(1, 10 ** 6))},
                    lambda cfg, p: _Disconnecting(cfg.sample_rate, cfg.n_axes, None, polls=p["polls"]))


def test_rig_check_reports_a_device_that_disconnects(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(backends.BUILTIN, "flaky", "test_rig_check:FLAKY")
    out = tmp_path / "r.json"
    assert main(["rig-check", "--backend", "flaky", "--duration", "1", "--json", str(out)]) == 1
    rep = json.loads(out.read_text())
    assert rep["ok"] is False
    assert any("disconnect" in e for e in rep["errors"])
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize("args, msg", [
    (["--backend", "nope"], "unknown backend 'nope'"),
    (["--block-size", "0"], "--block-size"),
    (["--test-voltage", "1e9"], "--test-voltage"),
    (["--param", "novalue"], "--param"),
    (["--json", "/"], "is a directory"),
])
def test_rig_check_bad_options_one_line(args, msg, capsys):
    assert main(["rig-check", "--duration", "0.2", *args]) in (1, 2)
    cap = capsys.readouterr()
    assert msg in cap.err or msg in cap.out, cap
    assert "Traceback" not in cap.err


class _FailsToStart(ClockedSim):
    """A device that opens, then refuses to start (wrong trigger line, a busy task …); it counts its closes."""

    closed = 0

    def start(self, *a, **kw):
        raise RuntimeError("start refused")

    def close(self):
        type(self).closed += 1
        super().close()


FAILS_TO_START = BackendSpec("fails_to_start", "test device", {},
                             lambda cfg, p: _FailsToStart(cfg.sample_rate, cfg.n_axes, None))


def test_rig_check_closes_a_device_that_opened_but_did_not_start(tmp_path, monkeypatch, capsys):
    """A failed link check must not leave the device open (a DAQ task or a controller connection held)."""
    monkeypatch.setitem(backends.BUILTIN, "fails_to_start", "test_rig_check:FAILS_TO_START")
    out = tmp_path / "r.json"
    assert main(["rig-check", "--backend", "fails_to_start", "--duration", "0.2", "--json", str(out)]) == 1
    rep = json.loads(out.read_text())
    assert "start refused" in rep["checks"]["link"]["error"]
    assert _FailsToStart.closed == 1


# -- through nidaqmx's own Task and stream classes, the device replaced at the interpreter (real-time clock) -------
NI = ["--backend", "nidaqmx", "--param", "ai_channels=Dev1/ai0,Dev1/ai1", "--param", "sensor_gain=[1.0, 1.0]"]


@pytest.fixture()
def ni_card(monkeypatch):
    pytest.importorskip("nidaqmx")
    from nidaqmx_fake import FakeDaq, install

    return install(monkeypatch, FakeDaq(latency=3))


def test_rig_check_measures_the_ao_ai_latency_of_a_loopback(ni_card, tmp_path, capsys):
    """AI wired to AO, 3 samples late: with latency_samples=1 the latency check fails and names the value to set;
    with the measured value it passes."""
    out = tmp_path / "r.json"
    assert main(["rig-check", *NI, "--loopback", "--duration", "1", "--json", str(out)]) == 1
    rep = json.loads(out.read_text())
    lat = rep["checks"]["latency"]
    assert lat["ok"] is False and lat["measured_latency_samples"] == 3 and rep["latency_samples"] == 3, lat
    assert "latency_samples=3" in lat["remedy"]
    assert all(c["ok"] for n, c in rep["checks"].items() if n != "latency"), rep["checks"]
    assert main(["rig-check", *NI, "--param", "latency_samples=3", "--loopback", "--duration", "1",
                 "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["ok"] and rep["checks"]["latency"]["residual_samples"] == 0 and rep["latency_samples"] == 3
    assert rep["checks"]["latency"]["axes"]["x"]["peak"] > 0.99


def test_rig_check_reports_an_underflow_as_underruns_not_a_device_failure(ni_card, tmp_path, capsys):
    """DAQmx -200290 raised by a write mid-stream: the driver's fault path (ramp, restart), the write-ahead check
    fails naming the setting, every other check still runs; the output ends at the safe voltage."""
    ni_card.fail_after["write_analog_f64"] = (40, -200290)
    out = tmp_path / "r.json"
    assert main(["rig-check", *NI, "--param", "latency_samples=3", "--duration", "1", "--json", str(out)]) == 1
    rep = json.loads(out.read_text())
    assert "device" not in rep["checks"], rep["checks"]
    wa = rep["checks"]["write_ahead"]
    assert wa["ok"] is False and wa["underruns"] + wa["underruns_before_streaming"] == 1 and "write_ahead" in wa["remedy"]
    assert rep["underruns_total"] == 1 and rep["checks"]["faults"] == {"ok": False, "underrun": 1, "overrun": 0,
                                                                       "disconnect": 0, "limit": 0, "controller": 0}
    assert rep["checks"]["safe_ramp"]["ok"] and rep["checks"]["slew_limit"]["ok"]
    assert any("underflow (-200290)" in e for e in rep["errors"])
    assert all(t.cleared for t in ni_card.tasks.values())
    assert abs(ni_card.ao_value["Dev1/ao0"]) < 1e-12 and abs(ni_card.ao_value["Dev1/ao1"]) < 1e-12


def test_rig_check_on_pi_gcs_through_the_tcp_emulator_judges_the_staircase_per_elapsed_time(tmp_path, capsys):
    """pi_gcs (pipython's PISocket against the GCS emulator on TCP): what does not apply (no hardware sample clock →
    sample clock and write-ahead; no sensor stream → latency) is skipped with the reason; the safe ramp, played as a
    paced staircase of set points, passes when judged per elapsed time between them although each stair is larger
    than one sample's allowed step; no fault."""
    pytest.importorskip("pipython")
    from gcs_emulator import GCSEmulator, GCSServer

    out = tmp_path / "pi.json"
    with GCSServer(GCSEmulator(), lifetime=120) as srv:
        code = main(["rig-check", "--backend", "pi_gcs", "--param", "address=127.0.0.1", "--param",
                     f"port={srv.port}", "--param", "servo_rate=20000", "--duration", "0.3", "--test-voltage", "5",
                     "--ramp-slew", "200", "--json", str(out)])
        assert any(line.startswith("SVA") for line in srv.emu.log)
    rep = json.loads(out.read_text())
    c = rep["checks"]
    assert c["sample_clock"]["ok"] is None and "sample clock" in c["sample_clock"]["skipped"]
    assert c["write_ahead"]["ok"] is None and "FIFO" in c["write_ahead"]["skipped"]
    assert c["latency"]["ok"] is None and "sensor" in c["latency"]["skipped"]
    ramp = c["safe_ramp"]
    assert ramp["ok"] is True and ramp["judged"] == "per elapsed time between set points", ramp
    assert ramp["setpoint_max_step_v"] > ramp["allowed_v"] >= ramp["max_step_v"] > 0, ramp   # stairs, paced
    assert ramp["samples"] >= ramp["min_samples"] and ramp["ends_at_safe"] is True
    assert c["slew_limit"]["ok"] is True and c["slew_limit"]["target_reached"] is True
    assert c["faults"]["ok"] is True and "controller" in c["faults"]
    assert code == 0 and rep["ok"] is True, rep
