"""Backends as plug-ins: entry-point discovery, per-backend parameter validation, the extras declared in setup.py."""
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros import backends
from piezo_ff_ros.backends import BackendError, get_spec

ROOT = Path(__file__).resolve().parents[1]


def test_a_lab_backend_is_found_through_its_entry_point(tmp_path, monkeypatch):
    pkg = tmp_path / "labrig"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent("""
        from piezo_ff_ros.core.hardware import LockstepSim
        from piezo_ff_ros.backends.base import BackendSpec, Param, int_range
        SPEC = BackendSpec("labrig", "a lab's own amplifier", {"channels": Param(2, "AO channels", int_range(1, 8))},
                           lambda cfg, p: LockstepSim(cfg.sample_rate, cfg.n_axes, None, name="labrig"))
        """))
    dist = tmp_path / "labrig-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: labrig\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[piezo_ff_ros.backends]\nlabrig = labrig:SPEC\nbroken = labrig:NOPE\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "labrig" in backends.available()
    spec = get_spec("labrig")
    assert spec.validate({}) == {"channels": 2}
    with pytest.raises(ConfigError, match=r"labrig\.channels"):
        spec.validate({"channels": 9})
    with pytest.raises(BackendError, match="plug-in 'broken'.*failed to load"):
        get_spec("broken")


@pytest.mark.parametrize("values, field", [({"mode": "fast"}, "sim.mode"), ({"fifo_depth": 2.5}, "sim.fifo_depth"),
                                           ({"noise_std": -1.0}, "sim.noise_std"), ({"nope": 1}, "sim.nope")])
def test_backend_parameters_validated_naming_the_field(values, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        get_spec("sim").validate(values)


def test_setup_declares_the_extras_and_the_entry_point_group(tmp_path):
    r = subprocess.run([sys.executable, "setup.py", "-q", "egg_info", "--egg-base", str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    info = next(tmp_path.glob("*.egg-info"))
    requires = (info / "requires.txt").read_text()
    assert "[nidaqmx]\nnidaqmx>=1.0" in requires and "[pipython]\npipython>=2.10" in requires
    eps = (info / "entry_points.txt").read_text()
    assert "[piezo_ff_ros.backends]" in eps
    for name in ("sim", "nidaqmx", "pi_gcs"):
        assert f"{name} = piezo_ff_ros.backends." in eps
