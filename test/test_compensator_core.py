"""CompensatorCore (core/compensator_core.py): the compensator node's logic without ROS — input bookkeeping, held-point
stamps, workspace clamp, bypass, parameter transactions (reject, no-op, background build failing → revert), status."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.compensator_core import (ERROR, OK, WARN, CompensatorCore, CompensatorSettings, ParameterBook,
                                                parse_config_yaml)
from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.param_map import config_to_params

N = 200                    # samples per block
DT = 50_000                # ns at 20 kHz
S0 = 1_000_000 * DT        # first stamp of the test streams
WALL = 7_777_777_777_123   # the fake wall clock [ns] (off the sample grid)


def make_core(base, factory=None, feedback=False, values=None, **settings):
    """A core as the node builds it, C(s) off (no H∞ synthesis: fast)."""
    book = ParameterBook(base)
    book.values.update(config_to_params(base))
    book.values["cascade.vibration"] = False
    book.values.update(values or {})
    cfg = book.end_declarations()
    return CompensatorCore(book, cfg, CompensatorSettings(**settings), factory=factory, wall_ns=lambda: WALL,
                           applied_feedback=lambda: feedback)


def held(n=N, x=10e-6, y=-5e-6):
    return np.tile([x, y], (n, 1))


def stamps(em):
    return [b.stamp for b in em.voltage]


def warnings(em):
    return [t for level, t in em.log if level == WARN]


@pytest.fixture(scope="module")
def base(paper_config):
    return paper_config


def test_gaps_late_blocks_and_a_restart_after_a_pause_are_counted(base):
    core = make_core(base)
    t = 100.0
    assert stamps(core.on_reference(S0, held(), t)) == [S0]                    # first block: nothing to compare
    assert not core.on_reference(S0 + N * DT, held(), t + 0.01).log              # contiguous
    em = core.on_reference(S0 + 3 * N * DT, held(), t + 0.02)                  # one block lost
    assert warnings(em) == [f"reference gap: {N} samples missing before stamp {S0 + 3 * N * DT}"]
    assert (core.input["gaps"], core.input["gap_samples"], core.input["late_blocks"]) == (1, N, 0)
    core.on_reference(S0 + 2 * N * DT, held(), t + 0.03)                       # the lost block, late
    assert (core.input["gaps"], core.input["late_blocks"]) == (1, 1)
    core.on_reference(S0 + 3 * N * DT, held(), t + 0.04)                       # continues the late block: fine
    assert (core.input["gaps"], core.input["late_blocks"]) == (1, 1)
    # a pause longer than max(hold_timeout 0.2, 0.5) s: a new stream may start anywhere, no gap
    em = core.on_reference(S0 + 10_000 * N * DT, held(), t + 0.6)
    assert not em.log and core.input["gaps"] == 1
    # with hold_timeout 2 s the same pause is no restart: a jump of up to 1 s is a gap
    core.commit([("hold_timeout", 2.0)])
    core.on_reference(S0 + (10_001 + 50) * N * DT, held(), t + 1.2)
    assert core.input["gaps"] == 2 and core.pacer.hold_timeout == 2.0
    # a jump of more than 1 s (a stray stamp, a new stream) is no gap: it never counts as lost samples
    em = core.on_reference(S0 + 10**9 * N * DT, held(), t + 1.3)
    assert core.input["jumps"] == 1 and core.input["gaps"] == 2 and "jumped" in warnings(em)[0]
    st = core.status()
    assert (st["input_gaps"], st["input_gap_samples"], st["input_late_blocks"]) == (2, N + 50 * N, 1)
    level, message, _ = core.diagnostics()
    assert level == WARN and "input_gaps 2" in message and "input_late_blocks 1" in message
    assert core.blocks == 8


def test_a_held_point_continues_the_stream_and_starts_on_the_wall_clock_grid(base):
    core = make_core(base, block_size=50)
    assert core.set_point([1e-6, 2e-6]).hold_timer == "start"
    assert stamps(core.process(core.pacer.block(), None, 0.0)) == [WALL // DT * DT]   # nothing before: wall clock
    core.on_reference(S0, held(), 1.0)
    first = core.process(core.pacer.block(), None, 1.5)
    second = core.process(core.pacer.block(), None, 1.6)
    assert stamps(first) + stamps(second) == [S0 + N * DT, S0 + (N + 50) * DT]       # right after the stream
    assert first.voltage[0].u.shape == (50, 2)
    assert core.input["gaps"] == 0 and core.input["late_blocks"] == 0
    assert core.reset().startswith("compensator states reset (config v1")
    assert core.pacer.point is None
    assert stamps(core.process(held(), None, 2.0)) == [WALL // DT * DT]              # reset: a new stream
    rejected = core.set_point([np.nan, 0.0])
    assert rejected.log == [(ERROR, "reference_point rejected: NaN/Inf")] and rejected.hold_timer is None


def test_workspace_clamp_counts_samples_and_warns_once_a_second(base):
    ws = (-20e-6, 20e-6, -20e-6, 20e-6)
    core, free = make_core(base, workspace=ws), make_core(base)
    block = held()
    block[:3, 0] = 1.0           # 3 samples outside in x
    block[3, 1] = -1.0           # 1 more in y
    em = core.on_reference(S0, block, 10.0)
    assert core.input["workspace_clamped_samples"] == 4
    assert warnings(em) == [f"reference outside the workspace {list(ws)} [m]: 4 samples clamped (total 4)"]
    clipped = np.clip(block, [-20e-6, -20e-6], [20e-6, 20e-6])
    np.testing.assert_array_equal(em.voltage[0].u, free.on_reference(S0, clipped, 10.0).voltage[0].u)
    assert not warnings(core.on_reference(S0 + N * DT, block, 10.5))                  # within 1 s: counted only
    assert core.input["workspace_clamped_samples"] == 8
    assert warnings(core.on_reference(S0 + 2 * N * DT, block, 11.2))                  # a second later: again
    assert core.diagnostics()[0] == WARN
    core.commit([("workspace", [])])                                                   # no workspace: not clamped
    core.on_reference(S0 + 3 * N * DT, block, 11.3)
    assert core.input["workspace_clamped_samples"] == 12


def test_bypass_forwards_the_block_unchanged(base):
    core = make_core(base, workspace=(-20e-6, 20e-6, -20e-6, 20e-6))
    volts = np.column_stack([np.linspace(-5.0, 90.0, N), np.linspace(3.0, 4.0, N)])
    assert not np.array_equal(core.on_reference(S0, volts, 1.0).voltage[0].u, volts)    # the cascade runs
    core.commit([("bypass", True)])
    em = core.on_reference(S0 + N * DT, volts, 1.01)
    np.testing.assert_array_equal(em.voltage[0].u, volts)
    assert em.voltage[0].stamp == S0 + N * DT and not em.log
    assert core.status()["bypass"] is True


def test_nan_reference_is_rejected_and_counted(base):
    core = make_core(base)
    bad = held()
    bad[5, 1] = np.inf
    em = core.on_reference(S0, bad, 1.0)
    assert em.voltage == [] and em.log == [(ERROR, "reference block rejected: NaN/Inf in the reference")]
    assert core.rejected_blocks == 1 and core.blocks == 0
    st = core.status()
    assert st["rejected_blocks"] == 1 and st["last_error"] == "reference block rejected: NaN/Inf in the reference"
    assert core.diagnostics()[0] == ERROR   # while it lasts
    assert core.diagnostics()[0] == WARN    # then the count stays


def test_the_first_block_of_a_version_announces_it(base):
    core = make_core(base)
    first = core.on_reference(S0, held(), 1.0).voltage[0]
    assert first.config is not None and list(first.config) == ["version", "stamp_ns", "config_yaml"]
    assert (first.config["version"], first.config["stamp_ns"]) == (1, S0)
    assert core.on_reference(S0 + N * DT, held(), 1.01).voltage[0].config is None
    assert core.propose([("cascade.creep", False)]).successful
    em = core.commit([("cascade.creep", False)])
    assert (OK, "configuration v2 requested (cascade.creep)") in em.log and em.diagnostics
    swapped = core.on_reference(S0 + 2 * N * DT, held(), 1.02).voltage[0]
    assert swapped.config is not None and (swapped.config["version"], swapped.config["stamp_ns"]) == \
        (2, S0 + 2 * N * DT)
    assert "creep: false" in swapped.config["config_yaml"].replace("'", "")
    assert (OK, "configuration v2 active") in core.poll().log


def test_a_rejected_change_keeps_the_running_config_and_says_why(base):
    core = make_core(base)
    before = dict(core.book.values)
    v = core.propose([("hysteresis.Dp", [1e-7, 2e-7])])                  # 2 values for a 2×2 matrix
    assert not v.successful and v.reason.startswith("hysteresis.Dp: ") and "\n" not in v.reason
    assert "(kept: hysteresis.Dp=[" in v.reason
    assert v.log == ((ERROR, f"parameter change rejected: {v.reason.split(' (kept: ')[0]}"),)
    assert core.book.values == before and core.book.take_candidate() is None
    for params, field in [([("workspace", [1.0, -1.0, 0.0, 1.0])], "workspace"),
                          ([("config_yaml", "crossfade: 0.1")], "config_yaml"),
                          ([("config_yaml", "creep.Cr.xz.k: 1.0")], "creep.Cr.xz.k"),
                          ([("preview.horizon_s", 5.0)], "preview.horizon_s"),
                          ([("learning.file", "/nonexistent/corr.npz")], "learning.file")]:
        v = core.propose(params)
        assert not v.successful and v.reason.startswith(f"{field}: ") and "\n" not in v.reason, (params, v)
    assert core.book.take_front() is None
    em = core.commit([])
    assert em.log == [] and core.hs.version == 1 and core.hs.pending_version is None


def test_while_declaring_a_change_is_only_checked(base):
    book = ParameterBook(base)
    assert not book.propose([("vibration.t_r", -1.0)]).successful
    assert book.propose([("cascade.creep", False)]).successful
    assert book.take_candidate() is None
    assert book.propose([("config_yaml", "creep.Cr.xz.k: 1.0")]).successful is False   # no such entry


def test_setting_the_running_values_creates_no_version(base):
    core = make_core(base)
    running = [(k, core.book.values[k]) for k in ("creep.Cr.xx.k", "cascade.creep", "hysteresis.Dp")]
    assert core.propose(running).successful
    em = core.commit(running)
    assert em.log == [(OK, "parameters set to the values that run (cascade.creep, creep.Cr.xx.k, hysteresis.Dp): "
                           "no new configuration")]
    assert not em.diagnostics and core.hs.version == 1 and core.hs.pending_version is None
    # through config_yaml: the same, and the parameters read back
    assert core.propose([("config_yaml", "cascade:\n  creep: true\n")]).successful
    em = core.commit([("config_yaml", "cascade:\n  creep: true\n")])
    assert em.readback == {"cascade.creep": True, "config_yaml": ""} and core.hs.pending_version is None


def test_config_yaml_is_one_change_and_reads_back(base):
    core = make_core(base)
    text = "creep.Cr.xx.den: [1.0, 0.12809, 0.001443844]\ncreep.Cr.xx.den_deg: [2]\n"
    assert parse_config_yaml(text) == {"creep.Cr.xx.den": [1.0, 0.12809, 0.001443844], "creep.Cr.xx.den_deg": [2]}
    assert core.propose([("config_yaml", text)]).successful
    em = core.commit([("config_yaml", text)])
    assert em.readback == {"creep.Cr.xx.den": [1.0, 0.12809, 0.001443844], "creep.Cr.xx.den_deg": [2],
                           "config_yaml": ""}
    assert core.book.values["creep.Cr.xx.den_deg"] == [2]
    assert (OK, "configuration v2 requested (creep.Cr.xx.den, creep.Cr.xx.den_deg)") in em.log


def test_a_failed_background_build_reverts_to_the_running_values(base):
    def factory(cfg, controller=None):
        if cfg.vibration.t_r == 0.5:
            raise ValueError("gamma 3.2 > gamma_max 2.0")
        return CompensatorCascade(cfg, controller=controller)

    core = make_core(base, factory=factory)
    running_t_r = core.book.values["vibration.t_r"]
    assert core.propose([("vibration.t_r", 0.5)]).successful
    em = core.commit([("vibration.t_r", 0.5)])
    assert em.log == [(OK, "configuration v2 requested (vibration.t_r); building in the background")]
    assert core.book.values["vibration.t_r"] == 0.5
    assert core.hs.wait_pending(30)
    em = core.poll()
    assert em.log == [(ERROR, "configuration v2 not applied: gamma 3.2 > gamma_max 2.0; parameters reverted to the "
                              "running configuration v1")]
    assert em.revert == {"vibration.t_r": running_t_r} and em.diagnostics
    assert core.book.values["vibration.t_r"] == running_t_r and core.hs.version == 1
    level, message, st = core.diagnostics()
    assert level == WARN and "configuration v2 not applied" in message and st["failed_builds"] == 1
    assert core.poll().log == []                                           # reported once
    # a later change is applied normally (v3: the failed v2 is not reused)
    assert core.propose([("cascade.creep", False)]).successful
    core.commit([("cascade.creep", False)])
    assert (OK, "configuration v3 active") in core.poll().log


def test_crossfade_and_block_size_reach_the_cascade_and_the_pacer(base):
    core = make_core(base)
    em = core.commit([("crossfade", 0.02), ("block_size", 400)])
    assert core.hs.crossfade_samples == 400 and core.pacer.block_size == 400 and em.hold_timer == "retime"
    assert core.settings.crossfade == 0.02 and core.settings.block_size == 400


def test_resync_follows_the_applied_voltage_and_warns_once_a_second(base):
    core = make_core(base, feedback=True)
    u = core.on_reference(S0, held(), 1.0).voltage[0].u
    assert core.on_applied(S0, u, 1.0).log == [] and core.hs.applied_blocks == 1
    u2 = core.on_reference(S0 + N * DT, held(), 1.01).voltage[0].u
    assert warnings(core.on_applied(S0 + N * DT, 0.5 * u2, 1.01)) == [
        "applied voltage differs from the command: hysteresis/creep states re-synchronised (1 so far)"]
    u3 = core.on_reference(S0 + 2 * N * DT, held(), 1.02).voltage[0].u
    assert core.on_applied(S0 + 2 * N * DT, 0.5 * u3, 1.02).log == [] and core.hs.resyncs == 2
    assert core.reject("voltage_applied", "no fields").log == [(ERROR, "voltage_applied block rejected: no fields")]
    assert core.status()["applied_rejected"] == 1
    without = make_core(base)                                    # no driver reports: nothing in flight
    without.on_reference(S0, held(), 1.0)
    assert without.status()["in_flight_blocks"] == 0


def test_status_keys(base):
    st = make_core(base).status()
    assert list(st) == ["config_version", "pending_version", "swaps", "failed_builds", "crossfading", "last_error",
                        "resyncs", "applied_blocks", "in_flight_blocks", "bypass", "blocks", "rejected_blocks",
                        "input_gaps", "input_gap_samples", "input_late_blocks", "input_jumps",
                        "input_workspace_clamped_samples", "applied_rejected", "stages", "order", "resync_active",
                        "preview_s", "learning_file", "reference_limit", "hysteresis_fallbacks"]
    assert (st["stages"], st["order"], st["resync_active"], st["preview_s"]) == ("creep,hysteresis", "paper", True,
                                                                                  0.0)
    level, message, _ = make_core(base).diagnostics()
    assert (level, message) == (OK, "config v1")


def test_a_front_change_refused_with_the_rest_of_its_set_never_takes_effect(base):
    """One atomic set: a valid tracking-front parameter and an invalid stage parameter (or workspace). The set is
    refused, so the front must stay as it runs — it was kept and applied at the next successful set."""
    core = make_core(base)
    for bad in (("hysteresis.Dp", [1e-7, 2e-7]), ("workspace", [1.0, -1.0, 0.0, 1.0])):
        v = core.propose([("preview.enabled", True), bad])
        assert not v.successful
        assert core.book.take_front() is None
        assert core.propose([("crossfade", 0.02)]).successful     # a later, unrelated change …
        core.commit([("crossfade", 0.02)])
        assert core.front.preview is None and core.book.front_values["preview.enabled"] is False   # … leaves it off
