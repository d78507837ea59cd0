"""The pi_gcs backend over the real pipython message layer against a command-level GCS emulator
(test/gcs_emulator.py).  No PI controller here (see docs/hardware.md)."""
import numpy as np
import pytest

pytest.importorskip("pipython")

from gcs_emulator import GCSEmulator  # noqa: E402

from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.hardware import DriverCore, DriverSettings  # noqa: E402
from piezo_ff_ros.backends import BackendError, get_spec  # noqa: E402
from piezo_ff_ros.backends.pi_gcs import PISetpointBackend, PITablePlayer, connect  # noqa: E402


def params(**kw):
    return get_spec("pi_gcs").validate({"servo_rate": 20000.0, "chunk": 50, **kw})


def test_table_mode_uploads_plays_and_reads_back_the_recorder():
    emu = GCSEmulator(plant=lambda u: 0.1 * u)
    dev, idn = connect(params(), gateway=emu)
    assert "E-727 emulator" in idn
    t = np.arange(1234) / 20000.0
    u = np.column_stack([50 * np.sin(2 * np.pi * 5 * t), 20 * np.cos(2 * np.pi * 5 * t)])
    player = PITablePlayer(dev, params(), 20000.0, 200.0)
    player.upload(u)
    y = player.play(timeout=5)
    np.testing.assert_allclose(y, 0.1 * u * 1e-6, rtol=1e-8, atol=1e-15)   # µm → m
    cmds = [c.split()[0] for c in emu.log]
    for c in ("SVO", "WAV", "WSL", "WGC", "WTR", "DRC", "RTR", "WGO", "WGO?", "DRR?"):
        assert c in cmds, c
    assert sum(c == "WAV" for c in cmds) == 2 * 25                # 1234 points in chunks of 50, per table
    assert emu.wtr == {1: (1, 0), 2: (1, 0)} and emu.wgc == {1: 1, 2: 1}
    assert not emu.err


def test_table_rate_must_be_whole_servo_cycles_and_tables_checked():
    emu = GCSEmulator()
    dev, _ = connect(params(), gateway=emu)
    with pytest.raises(BackendError, match="servo_rate"):
        PITablePlayer(dev, params(servo_rate=50000.0), 20000.0, 200.0)
    p = PITablePlayer(dev, params(servo_rate=50000.0), 25000.0, 200.0)
    assert p.table_rate == 2
    with pytest.raises(ValueError, match="±200"):
        p.upload(np.full((10, 2), 300.0))


def test_setpoint_mode_through_the_driver_core_reports_the_staircase():
    emu = GCSEmulator()
    cfg = load_config()
    be = PISetpointBackend(cfg, params(), gateway=emu)
    core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits), be, now=lambda: 0.0)
    core.start()
    assert emu.servo == {"1": False, "2": False}
    em = core.on_block(0, np.tile([[10.0, -5.0]], (100, 1)))
    assert emu.sva == {"1": 10.0, "2": -5.0}
    (stamp, a), = em.applied
    assert stamp == 0 and a.shape == (100, 2)
    np.testing.assert_array_equal(a[:-1], 0.0)                  # held at the previous set-point …
    np.testing.assert_array_equal(a[-1], [10.0, -5.0])          # … until the block's last value lands
    assert not em.displacement and not emu.err
    core.close()
    assert emu.sva == {"1": 0.0, "2": 0.0} or not emu.connected


def test_controller_error_is_reported_as_a_fault_not_a_traceback():
    emu = GCSEmulator()
    cfg = load_config()
    be = PISetpointBackend(cfg, params(axes="1,7"), gateway=emu)    # axis 7 does not exist: GCS error 15
    with pytest.raises(Exception) as exc:
        be.start(np.zeros(2))
    assert "pi_gcs" in str(exc.value)


def test_no_controller_here_connect_fails_with_one_line():
    with pytest.raises(BackendError, match="pi_gcs: cannot connect"):
        connect(params(interface="tcpip", address="127.0.0.1", port=9))
