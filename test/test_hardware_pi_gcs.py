"""The pi_gcs backend through pipython's own PISocket + GCSMessages code path, against a GCS 2.0 controller emulator
served on a loopback TCP port (test/gcs_emulator.py).  No PI controller here (see docs/hardware.md).

Every path that moves the output is checked on the emulator's record of set points with their arrival times: the
largest step between two consecutive values and the rate against the time that elapsed between them."""
import time
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("pipython")

from gcs_emulator import GCSEmulator, GCSServer  # noqa: E402

from piezo_ff_ros.backends import BackendError, get_spec  # noqa: E402
from piezo_ff_ros.backends.pi_gcs import GCSFault, PISetpointBackend, PITablePlayer, TableError, connect  # noqa: E402
from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.hardware import DriverCore, DriverSettings  # noqa: E402
from piezo_ff_ros.core.hardware.contract import Disconnect  # noqa: E402

SAFE_RAMP_RATE = 1.0e4      # V/s: SafeRampConfig's default slew (the duration usually makes it slower)


def params(srv, **kw):
    return get_spec("pi_gcs").validate({"address": "127.0.0.1", "port": srv.port, "servo_rate": 20000.0,
                                        "chunk": 50, "timeout_ms": 500, **kw})


def config(slew=1000.0, voltage=200.0):
    cfg = load_config()
    return replace(cfg, limits=replace(cfg.limits, slew=slew, voltage=voltage)).validate()


def wait_until(cond, timeout=5.0):
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise AssertionError("condition not reached")
        time.sleep(0.005)


def steps(emu, since=0.0):
    """(dt [s], |dv| max over axes [V], values) between consecutive values that reached the output after ``since``."""
    t, v = emu.output_events()
    keep = t >= since
    t, v = t[keep], v[keep]
    return np.diff(t), np.abs(np.diff(v, axis=0)).max(axis=1) if len(v) > 1 else np.zeros(0), v


def assert_paced(emu, rate, since=0.0, step_max=1.0, slack_s=2e-4, start=None):
    """No step above ``step_max`` and none faster than ``rate`` V/s over the time since the previous value (with
    ``slack_s`` for the emulator thread's own scheduling); ``start``: the value held before the first event."""
    dt, dv, v = steps(emu, since)
    if start is not None and len(v):
        dv = np.concatenate([[np.abs(v[0] - start).max()], dv])
        dt = np.concatenate([[np.inf], dt])
    assert dv.size, "nothing reached the output"
    assert dv.max() <= step_max + 1e-9, f"step of {dv.max():.3f} V between two set points"
    worst = np.max(dv - rate * (dt + slack_s))
    assert worst <= 1e-9, f"a step {worst:.3f} V faster than {rate:g} V/s allows"
    return v


# -- connection ------------------------------------------------------------------------------------------------------
def test_connects_through_pipythons_own_pisocket_and_reads_the_controller():
    with GCSServer(GCSEmulator(vmin=-30.0, vmax=130.0)) as srv:
        link = connect(params(srv))
        try:
            from pipython.pidevice.interfaces.pisocket import PISocket
            assert isinstance(link.gateway, PISocket)
            assert "E-727 emulator" in link.info.idn
            assert link.info.axes == ("1", "2")
            assert link.info.vmin == (-30.0, -30.0) and link.info.vmax == (130.0, 130.0)
            for q in ("*IDN?", "SAI?", "VMA? 1 2", "VMI? 1 2"):
                assert q in srv.emu.log, q
        finally:
            link.close()
        wait_until(lambda: srv.open_connections == 0)


def test_dll_only_when_asked_and_one_line_without_it():
    with GCSServer() as srv:
        with pytest.raises(BackendError, match=r"pi_gcs.use_dll: PI's GCS shared library is not usable") as exc:
            connect(params(srv, use_dll=True))
        assert "\n" not in str(exc.value)


def test_no_controller_here_connect_fails_with_one_line():
    with pytest.raises(BackendError, match="pi_gcs: cannot connect") as exc:
        connect({**get_spec("pi_gcs").validate({}), "address": "127.0.0.1", "port": 9})
    assert "\n" not in str(exc.value)


def test_axis_missing_and_range_beyond_the_controllers_are_refused_with_one_line():
    with GCSServer(GCSEmulator(vmin=-30.0, vmax=130.0)) as srv:
        with pytest.raises(BackendError, match=r"pi_gcs.axes: axis '7' is not on the controller"):
            connect(params(srv, axes="1,7"))
        with pytest.raises(BackendError, match=r"voltage range of piezo channels \[1, 5\] .*pi_gcs.piezo_channels"):
            connect(params(srv, piezo_channels="1,5"))
        be = PISetpointBackend(config(voltage=200.0), params(srv))
        with pytest.raises(BackendError, match=r"limits.voltage: ±200 V exceeds axis 1's range \[-30, 130\]"):
            be.start(np.zeros(2))
        assert not any(c.startswith("SVA") for c in srv.emu.log)
        wait_until(lambda: srv.open_connections == 0)


# -- set-point mode ------------------------------------------------------------------------------------------------------
def test_start_reads_the_held_voltage_and_ramps_from_it_as_a_paced_staircase():
    with GCSServer(GCSEmulator(output=[20.0, -10.0])) as srv:
        be = PISetpointBackend(config(), params(srv))
        t0 = time.monotonic()
        be.start(np.zeros(2))
        took = time.monotonic() - t0
        assert "VOL? 1 2" in srv.emu.log
        v = assert_paced(srv.emu, 20.0 / 0.05, start=np.array([20.0, -10.0]))   # 20 V over the 50 ms ramp
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        assert took >= 0.05
        (k0, a), = be.take_applied()
        assert k0 == 0 and a.shape[0] == 1000 and np.allclose(a[-1], 0.0)
        be.close()


def test_driver_blocks_are_paced_to_their_sample_period_and_close_ramps_to_safe():
    cfg = config(slew=1000.0)
    with GCSServer() as srv:
        be = PISetpointBackend(cfg, params(srv))
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be)
        core.start()
        t = np.arange(8000) / cfg.sample_rate                       # 0.4 s, 20 V at 2 Hz: ≤ 252 V/s
        u = np.column_stack([20 * np.sin(2 * np.pi * 2 * t), 10 * np.sin(2 * np.pi * 2 * t)])
        t0 = time.monotonic()
        for i in range(0, 8000, 1000):
            core.on_block(int(i * 50_000), u[i:i + 1000])
        took = time.monotonic() - t0
        assert took >= 0.4, f"0.4 s of set points went out in {took:.3f} s"
        assert_paced(srv.emu, 20 * 2 * np.pi * 2 * 1.01, start=np.zeros(2))
        held = srv.emu.output[:]
        assert abs(held[0]) > 1.0                                    # a non-zero voltage to come back from
        t_close = time.monotonic()
        core.close()
        v = assert_paced(srv.emu, abs(held[0]) / 0.05 * 1.01, since=t_close, start=np.array(held))
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        wait_until(lambda: srv.open_connections == 0)                 # close() closed the socket


def test_the_drivers_stale_input_ramp_reaches_the_controller_as_a_paced_staircase():
    cfg = config(slew=1000.0)
    with GCSServer() as srv:
        be = PISetpointBackend(cfg, params(srv))
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be)
        core.start()
        core.on_block(0, np.tile([[20.0, -10.0]], (1000, 1)))         # slewed to 20 V at 1000 V/s, held
        assert srv.emu.output == [20.0, -10.0]
        t_hold = time.monotonic()
        wait_until(lambda: core.tick() is not None and core.state == "safe", timeout=5)
        v = assert_paced(srv.emu, 20.0 / 0.05 * 1.01, since=t_hold, start=np.array([20.0, -10.0]))
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        assert len(v) >= 20                                            # a staircase, not one 20 V step
        core.close()


def test_blocks_fed_at_the_nominal_rate_never_trip_the_stale_input_ramp():
    """A set point write lasts its block's duration: blocks as long as the stale timeout (and longer), each sent as
    soon as the previous one has played, with a tick in between (as the node's timer does), keep the driver active;
    the stale ramp still comes once the input really stops."""
    cfg = config(slew=1000.0)
    stale = cfg.limits.stale_timeout
    with GCSServer() as srv:
        be = PISetpointBackend(cfg, params(srv))
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be)
        log = list(core.start().log)
        n = int(round(1.25 * stale * cfg.sample_rate))
        stamp = 0
        for i in range(4):
            u = np.tile([[5.0 + i, -2.0]], (n, 1))
            log += core.on_block(stamp, u).log
            log += core.tick().log
            assert core.state == "active", (i, log)
            stamp += n * core.period_ns
        assert not any("no voltage block" in m for _, m in log), log
        t_stop = time.monotonic()
        wait_until(lambda: core.tick() is not None and core.state == "safe", timeout=5)
        assert time.monotonic() - t_stop >= stale * 0.9
        core.close()


def test_a_controller_error_is_a_named_fault_and_the_driver_ramps_to_safe_from_the_last_accepted_value():
    """A GCS error on a set point (302) reaches the driver core as a named ``limit`` fault, not a lost link: the core
    ramps from the last value the controller accepted to safe as a paced staircase (≤ 1 V per set point, no faster
    than the safe ramp), ``/diagnostics`` names the code and text, and the next block is accepted again."""
    cfg = config(slew=1000.0)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv))
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be)
        applied = []
        log = []

        def take(em):
            applied.extend(em.applied)
            log.extend(m for _, m in em.log)

        take(core.start())
        ramp_up = np.column_stack([np.linspace(0, 30, 2000), np.linspace(0, -15, 2000)])   # 300 V/s
        take(core.on_block(0, ramp_up[:1000]))
        emu.inject_error("SVA", 302, after=10)                      # the 11th set point of the next block fails
        take(core.on_block(1000 * 50_000, ramp_up[1000:]))
        wait_until(lambda: take(core.tick()) is None and core.state == "safe" and emu.output == [0.0, 0.0])
        text = " | ".join(log)
        assert "controller error 302 (Voltage out of limits)" in text, text
        assert "lost" not in text and "output stopped" not in text, text
        assert core.faults["limit"] == 1 and core.state == "safe"
        t, v = emu.output_events()
        # the last accepted value: the highest point of the staircase; the ramp starts from it, paced
        top = int(np.argmax(v[:, 0]))
        assert 10.0 < v[top, 0] < 30.0
        after = v[top:]
        assert np.abs(np.diff(after, axis=0)).max() <= 1.0 + 1e-9
        assert_paced(emu, v[top, 0] / 0.05 * 1.02, since=t[top])   # the safe ramp: 50 ms from the top
        assert t[-1] - t[top] >= 0.05 * 0.95                        # the safe ramp's duration, in time
        st = core.status()
        assert "302" in st["last_fault"] and "Voltage out of limits" in st["last_fault"], st
        level, msg = core.health()
        assert "controller error 302 (Voltage out of limits)" in msg, msg
        # every sample of the stream applied exactly once, the ramp included, ending at safe
        k = [s // 50_000 for s, _ in applied]
        n = [a.shape[0] for _, a in applied]
        assert k[0] == 0 and all(k[i + 1] == k[i] + n[i] for i in range(len(k) - 1)), list(zip(k, n))
        whole = np.vstack([a for _, a in applied])
        np.testing.assert_allclose(whole[-1], [0.0, 0.0])
        # input resumes after the safe state: the next block is played, not ignored
        log.clear()
        take(core.on_block(core.next_stamp, np.tile([[2.0, 1.0]], (400, 1))))
        assert not any("ignored" in m for m in log), log
        assert core.state == "active" and emu.output == [2.0, 1.0]
        core.close()
        assert emu.output == [0.0, 0.0]
        wait_until(lambda: srv.open_connections == 0)


def test_a_controller_error_during_the_start_ramp_still_ends_at_safe_by_a_paced_ramp():
    """The output holds 20 V at start; a set point of the start ramp is refused: the driver ramps on from the value
    the controller holds to safe, paced, instead of leaving the output mid-way."""
    cfg = config(slew=1000.0)
    emu = GCSEmulator(output=[20.0, -10.0])
    emu.inject_error("SVA", 302, after=5)
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv))
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be)
        log = [m for _, m in core.start().log]
        wait_until(lambda: log.extend(m for _, m in core.tick().log) is None and emu.output == [0.0, 0.0],
                   timeout=3)
        assert any("controller error 302" in m for m in log), log
        assert core.faults["limit"] == 1 and core.state == "safe"
        assert_paced(emu, 20.0 / 0.05 * 1.02, start=np.array([20.0, -10.0]))
        core.close()


def test_a_controller_error_holds_the_last_accepted_set_point_and_names_it_in_the_fault():
    """At the backend: a refused set point fills the rest of the block with the last accepted value (every sample
    reported once), the fault (kind ``limit``, code 302, its text) carries that value as ``held``, and the link
    stays usable: the next write is played (the driver's safe ramp goes through it)."""
    cfg = config(slew=1000.0)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv))
        be.start(np.zeros(2))
        be.write(0, np.column_stack([np.linspace(0, 10, 1000), np.zeros(1000)]))
        emu.inject_error("SVA", 302)
        be.write(1000, np.full((100, 2), [10.0, 0.0]) + np.linspace(0, 0.5, 100)[:, None])
        with pytest.raises(GCSFault, match=r"controller error 302 \(Voltage out of limits\)") as exc:
            be.poll()
        assert exc.value.kind == "limit" and exc.value.code == 302
        np.testing.assert_allclose(exc.value.held, emu.output)
        blocks = be.take_applied()
        k = 0
        for k0, a in blocks:
            assert k0 == k
            k += a.shape[0]
        assert k == be.write_index == 1100
        np.testing.assert_allclose(blocks[-1][1][-1], exc.value.held)
        be.write(1100, np.tile(exc.value.held, (10, 1)) * 0.9)
        np.testing.assert_allclose(emu.output, exc.value.held * 0.9)
        be.close()
        np.testing.assert_allclose(emu.output, [0.0, 0.0])


def test_ctrl_c_in_the_middle_of_a_block_then_close_ramps_from_the_last_accepted_set_point():
    cfg = config(slew=1000.0)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv))
        be.start(np.zeros(2))
        sleeps = []

        def sleep(d):                                 # SIGINT arrives while the staircase waits
            sleeps.append(d)
            if len(sleeps) == 40:
                raise KeyboardInterrupt
            time.sleep(d)

        be.stairs._sleep = sleep
        with pytest.raises(KeyboardInterrupt):
            be.write(0, np.column_stack([np.linspace(0, 40, 4000), np.linspace(0, -20, 4000)]))   # 200 V/s
        held = np.array(emu.output)
        assert held[0] > 1.0
        t_close = time.monotonic()
        be.close()                                    # what the driver does on SIGINT
        v = assert_paced(emu, max(200.0, held[0] / 0.05) * 1.01, since=t_close, start=held)
        np.testing.assert_allclose(v[-1], [0.0, 0.0])


def test_a_dropped_connection_is_a_disconnect_not_a_hang():
    cfg = config(slew=1000.0)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv))
        be.start(np.zeros(2))
        emu.drop_after(3)
        t0 = time.monotonic()
        be.write(be.write_index, np.column_stack([np.linspace(0, 10, 1000), np.zeros(1000)]))
        with pytest.raises(Disconnect, match="link to the controller lost"):
            be.poll()
        assert time.monotonic() - t0 < 2.0
        be.close()


def test_an_unanswered_set_point_times_out_as_a_lost_link_without_spinning_a_core():
    cfg = config(slew=1000.0)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        be = PISetpointBackend(cfg, params(srv, timeout_ms=300))
        be.start(np.zeros(2))
        emu.mute("ERR?")                                             # pipython checks every command with ERR?
        cpu0, t0 = time.thread_time(), time.monotonic()
        be.write(be.write_index, np.column_stack([np.linspace(0, 5, 1000), np.zeros(1000)]))
        wall, cpu = time.monotonic() - t0, time.thread_time() - cpu0
        with pytest.raises(Disconnect, match="link to the controller lost"):
            be.poll()
        assert 0.3 <= wall < 2.0
        assert cpu < 0.05 * wall + 0.02, f"{cpu:.2f} s of CPU in {wall:.2f} s"   # pipython alone spins (this thread only: the emulator and other tests' threads share the process)
        be.close()


# -- table mode ----------------------------------------------------------------------------------------------------------
def table(n=2000, fs=20000.0, amp=(50.0, 20.0)):
    t = np.arange(n) / fs
    return np.column_stack([amp[0] * np.sin(2 * np.pi * 10 * t) + amp[0], amp[1] * np.cos(2 * np.pi * 10 * t)])


def test_table_mode_waits_on_the_generator_running_and_ends_at_safe_by_a_ramp():
    cfg = config(slew=1.0e5)
    emu = GCSEmulator(plant=lambda u: 0.1 * u, output=[3.0, 0.0])
    with GCSServer(emu) as srv:
        player = PITablePlayer(cfg, params(srv))
        u = table()
        applied, y = player.play(u, timeout=5)
        np.testing.assert_allclose(y, 0.1 * u * 1e-6, rtol=1e-8, atol=1e-15)    # µm → m
        np.testing.assert_array_equal(applied, u)
        cmds = [c.split()[0] if c.strip() else c for c in emu.log]
        assert "\t" in cmds and "WGO?" not in cmds                        # '#9', not the start mode
        assert cmds.count("WAV") == 2 * 40
        assert emu.wtr == {1: (1, 0), 2: (1, 0)} and emu.wgc == {1: 1, 2: 1}
        assert not emu.err
        # ramp in from the held 3 V to u[0] = (50, 20) V, the table at its own rate, ramp out from u[-1]: never
        # more than 1 V between two values, the ramps at the safe ramp's pace (≥ 50 ms), the table at the slew limit
        v = assert_paced(emu, cfg.limits.slew, start=np.array([3.0, 0.0]))
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        src = [e[2] for e in sorted(emu.events, key=lambda e: e[0])]
        first, last = src.index("WAV"), len(src) - 1 - src[::-1].index("WAV")
        t, v = emu.output_events()
        assert set(src[first:last + 1]) == {"WAV"} and last - first + 1 == u.shape[0]
        for seg, v0, dist in ((slice(0, first), [3.0, 0.0], 47.0), (slice(last + 1, None), v[last], np.abs(u[-1]).max())):
            tt, vv = t[seg], v[seg]
            dv = np.abs(np.diff(np.vstack([v0, vv]), axis=0)).max(axis=1)
            assert dv.max() <= 1.0 + 1e-9
            assert np.all(dv[1:] <= dist / 0.05 * 1.01 * (np.diff(tt) + 2e-4))
            assert tt[-1] - tt[0] >= 0.045                              # the ramp took its 50 ms
        player.close()
        wait_until(lambda: srv.open_connections == 0)


def test_table_checks_capacity_and_range_before_uploading():
    cfg = config(slew=1.0e5)
    with GCSServer(GCSEmulator(vmin=-30.0, vmax=130.0, wave_points=1000)) as srv:
        player = PITablePlayer(cfg, params(srv))
        with pytest.raises(ValueError, match=r"2000 samples exceed the wave table capacity 1000 \(WMS\?\)"):
            player.play(table(2000))
        with pytest.raises(ValueError, match=r"sample\(s\) of axis 1 outside the controller's range \[-30, 130\]"):
            player.play(table(500, amp=(70.0, 10.0)))
        with pytest.raises(ValueError, match=r"beyond limits.slew"):
            player.play(np.column_stack([np.r_[0.0, 50.0], np.zeros(2)]))
        assert not any(c.startswith(("WAV", "SVA", "WGO")) for c in srv.emu.log)
        player.close()
    with GCSServer(GCSEmulator(record_points=4000, record_tables=4)) as srv:      # 1000 points per record table
        player = PITablePlayer(cfg, params(srv))
        with pytest.raises(ValueError, match=r"1500 samples exceed the data recorder capacity 1000 per table"):
            player.play(table(1500))
        assert not any(c.startswith(("WAV", "SVA", "WGO")) for c in srv.emu.log)
        player.close()


def test_a_controller_error_in_table_mode_cleans_up_and_ramps_to_safe():
    cfg = config(slew=1.0e5)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        player = PITablePlayer(cfg, params(srv))
        emu.inject_error("WTR", 405)
        with pytest.raises(TableError, match=r"controller error 405 \(Wave parameter out of range\)") as exc:
            player.play(table(1000))
        assert exc.value.code == 405 and "\n" not in str(exc.value)
        v = assert_paced(emu, 100.0 / 0.05 * 1.01, start=np.zeros(2))
        np.testing.assert_allclose(v[-1], [0.0, 0.0])                 # it went to u[0] = 50 V and came back
        assert v.max() >= 49.0
        assert not emu.generator_running()
        player.close()


def test_ctrl_c_during_a_table_play_stops_the_generator_and_ramps_to_safe():
    cfg = config(slew=1.0e5)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        player = PITablePlayer(cfg, params(srv))
        running = player.link.dev.IsGeneratorRunning
        calls = []

        def interrupted(gens):                       # SIGINT while waiting on the generator
            calls.append(1)
            # call 1: the "already running?" check before the upload; call 2: the first look once WGO started it.
            # Interrupting that one (not a later poll) keeps the check independent of the host's load: a 2nd poll
            # 1 s late found the table played out and no interrupt came (seen at load ~10)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return running(gens)

        player.link.dev.IsGeneratorRunning = interrupted
        with pytest.raises(KeyboardInterrupt):
            player.play(table(20000), timeout=5)                      # 1 s of table
        assert not emu.generator_running()
        assert emu.log.count("WGO 1 0 2 0") == 1
        src = [e[2] for e in sorted(emu.events, key=lambda e: e[0])]
        assert src[-1] == "SVA"                                       # ramped after the generator stopped
        assert_paced(emu, max(cfg.limits.slew, 100.0 / 0.05), start=np.zeros(2))
        np.testing.assert_allclose(emu.output, [0.0, 0.0])
        player.close()


def test_a_connection_dropped_during_a_table_play_is_one_line_and_no_hang():
    cfg = config(slew=1.0e5)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        player = PITablePlayer(cfg, params(srv))
        n_before = len(emu.log)
        emu.drop_after(300)                       # after the ramp in, during the upload (WAV + ERR? per chunk)
        t0 = time.monotonic()
        with pytest.raises(TableError, match=r"table mode stopped: .*the controller holds its last value") as exc:
            player.play(table(2000), timeout=2)
        assert "\n" not in str(exc.value)
        assert time.monotonic() - t0 < 3.0
        assert emu.dropped and any(c.startswith("WAV") for c in emu.log[n_before:])
        player.close()


def test_an_unanswered_drr_query_times_out_without_spinning_a_core_and_ramps_to_safe():
    cfg = config(slew=1.0e5)
    emu = GCSEmulator()
    with GCSServer(emu) as srv:
        player = PITablePlayer(cfg, params(srv, timeout_ms=400))
        emu.mute("DRR?")
        spent = {}
        query = player.link.dev.qDRR

        def timed_query(*args):                     # the CPU this process spends while the query stays unanswered
            cpu0, t0 = time.thread_time(), time.monotonic()
            try:
                return query(*args)
            finally:
                spent.update(wall=time.monotonic() - t0, cpu=time.thread_time() - cpu0)

        player.link.dev.qDRR = timed_query
        with pytest.raises(TableError, match="no answer"):
            player.play(table(1000), timeout=2)
        wall, cpu = spent["wall"], spent["cpu"]
        assert wall >= 0.4
        assert cpu < 0.05 * wall + 0.01, f"{cpu:.2f} s of CPU in {wall:.2f} s"   # pipython alone spins
        t, v = emu.output_events()
        np.testing.assert_allclose(v[-1], [0.0, 0.0])
        player.close()
        wait_until(lambda: srv.open_connections == 0)


def test_a_late_host_stretches_nothing_it_can_skip_and_never_hurries_a_set_point():
    """With every sleep overshooting by 3 ms (a loaded machine), the staircase keeps about real time by skipping
    scheduled set points, and two set points are never closer in time than the samples between them."""
    from piezo_ff_ros.backends.pi_gcs import Staircase

    now = [0.0]                                                      # a host clock of the test's own

    def sleep(d):
        now[0] += d + 0.003

    sends = []
    st = Staircase(lambda v: sends.append((now[0], np.array(v))), 20000.0, 1.0, 20, np.zeros(2), sleep=sleep,
                   clock=lambda: now[0])
    t = np.arange(4000) / 20000.0                                   # 0.2 s of a 50 V/s ramp: 10 V
    u = np.column_stack([50.0 * t, -25.0 * t])
    for i in range(0, 4000, 1000):
        st.play(u[i:i + 1000])
    took = now[0]
    ts = np.array([s[0] for s in sends])
    vs = np.vstack([np.zeros(2)] + [s[1] for s in sends])
    dv = np.abs(np.diff(vs, axis=0)).max(axis=1)
    assert dv.max() <= 1.0 + 1e-9
    assert np.all(dv[1:] <= 50.0 * np.diff(ts) + 1e-9)              # never faster than the stream's own slope
    np.testing.assert_allclose(vs[-1], u[-1])
    assert took < 0.25, f"0.2 s took {took:.2f} s"                 # ~real time: it skipped rather than lagged
    assert st.skipped > 0


def test_connects_through_pipythons_own_piserial_on_a_serial_port():
    """RS-232 / the controllers' USB serial ports: pipython's PISerial (pyserial) on a pseudo-terminal served by the
    emulator; the same start ramp as over TCP."""
    pytest.importorskip("serial")
    from gcs_emulator import GCSSerialServer

    with GCSSerialServer(GCSEmulator(output=[5.0, 0.0])) as srv:
        cfg = config()
        p = get_spec("pi_gcs").validate({"interface": "serial", "address": srv.port, "baudrate": 115200,
                                         "timeout_ms": 500})
        be = PISetpointBackend(cfg, p)
        be.start(np.zeros(2))
        from pipython.pidevice.interfaces.piserial import PISerial
        assert isinstance(be.link.gateway, PISerial)
        assert "E-727 emulator" in be.link.info.idn
        assert_paced(srv.emu, 5.0 / 0.05 * 1.01, start=np.array([5.0, 0.0]))
        be.close()
        assert srv.emu.output == [0.0, 0.0]
