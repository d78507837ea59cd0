"""``piezo-ff rig-check``: end to end on the clocked simulator (and lockstep), a failing device, bad options."""
import json

import numpy as np
import pytest

from piezo_ff_ros.cli import main
from piezo_ff_ros.core.hardware import ClockedSim
from piezo_ff_ros import backends
from piezo_ff_ros.backends.base import BackendSpec, Param, int_range


def test_rig_check_sim_clocked_writes_the_contract_keys(tmp_path, capsys):
    out, md = tmp_path / "rig.json", tmp_path / "rig.md"
    # a generous write-ahead: the machine running the tests is shared and Python's timers jitter
    code = main(["rig-check", "--backend", "sim", "--duration", "2", "--write-ahead", "0.2",
                 "--json", str(out), "--md", str(md)])
    rep = json.loads(out.read_text())
    for key in ("ok", "sample_rate_hz", "latency_samples", "underruns", "safe_ramp_max_step_v"):
        assert key in rep
    # a wall-clock paced device on a shared host may underrun: then the check must say so, not pass
    assert code == (0 if rep["ok"] else 1), rep
    assert rep["ok"] is (rep["underruns"] == 0 and all(c.get("ok", True) for c in rep["checks"].values()
                                                       if isinstance(c, dict))), rep
    assert abs(rep["sample_rate_hz"] / 20000.0 - 1) < 0.02
    assert rep["latency_samples"] == 2
    assert 0 < rep["safe_ramp_max_step_v"] <= 1.0e4 / 20000.0
    assert rep["checks"]["link"]["clocked"] is True
    assert rep["checks"]["slew_limit"]["target_reached"] is True
    assert "| safe_ramp | yes |" in md.read_text()


def test_rig_check_lockstep_and_bad_backend_parameter(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["rig-check", "--backend", "sim", "--param", "mode=lockstep", "--duration", "0.5",
                 "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["ok"] and rep["latency_samples"] == 0 and rep["checks"]["link"]["clocked"] is False
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
