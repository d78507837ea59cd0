"""Type checking gate: mypy, configured in setup.cfg, passes ``--strict`` on all of piezo_ff_ros/core.

Every module found under ``piezo_ff_ros/core`` is listed in the strict section of setup.cfg (a new core module must
be added there), every strict flag stays on, no ``ignore_errors`` exemption exists, and every ``# type: ignore``
carries an error code and a reason.
"""
from __future__ import annotations

import configparser
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "setup.cfg"
CORE = ROOT / "piezo_ff_ros" / "core"

# mypy --strict, spelled as per-module options (warn_redundant_casts and warn_unused_configs are global-only and
# set in [mypy]).
STRICT_FLAGS = {
    "disallow_any_generics": "True",
    "disallow_subclassing_any": "True",
    "disallow_untyped_calls": "True",
    "disallow_untyped_defs": "True",
    "disallow_incomplete_defs": "True",
    "check_untyped_defs": "True",
    "disallow_untyped_decorators": "True",
    "warn_unused_ignores": "True",
    "warn_return_any": "True",
    "implicit_reexport": "False",
    "strict_equality": "True",
    "extra_checks": "True",
}

# Modules that passed --strict when the gate was introduced: they may never leave the strict section.
STRICT_FLOOR = {
    "piezo_ff_ros.core.units",
    "piezo_ff_ros.core._jit",
    "piezo_ff_ros.core.jsonable",
    "piezo_ff_ros.core.stage",
    "piezo_ff_ros.core.lti",
    "piezo_ff_ros.core.config",
    "piezo_ff_ros.core.checks",
    "piezo_ff_ros.core.param_map",
    "piezo_ff_ros.core.commissioning",
    "piezo_ff_ros.core.characterisation",
    "piezo_ff_ros.core.characterisation_graph",
    "piezo_ff_ros.core.hot_swap",
    "piezo_ff_ros.core.experiments",
    "piezo_ff_ros.core.analysis",
    "piezo_ff_ros.core.metrics",
    "piezo_ff_ros.core.reproduce",
    "piezo_ff_ros.core.trajectories",
    "piezo_ff_ros.core.hardware.contract",
    "piezo_ff_ros.core.hardware.simulated_device",
    "piezo_ff_ros.core.hardware.stream",
    "piezo_ff_ros.core.models.plant",
    "piezo_ff_ros.core.models.creep",
    "piezo_ff_ros.core.models.bouc_wen",
    "piezo_ff_ros.core.models.dynamics",
    "piezo_ff_ros.core.models.effects",
    "piezo_ff_ros.core.compensators.hysteresis",
    "piezo_ff_ros.core.compensators.creep",
    "piezo_ff_ros.core.compensators.vibration",
    "piezo_ff_ros.core.compensators.cascade",
    "piezo_ff_ros.core.identification.goodness_of_fit",
    "piezo_ff_ros.core.synthesis.reduction",
    "piezo_ff_ros.core.synthesis.hinf",
}

# The only exemptions (ignore_errors) allowed: none any more (the last ones, for diagnosis/*, tracking/*,
# hardware.driver_core and safety, were cleaned).  Never add one.
EXEMPT_CEILING: set[str] = set()


def _config() -> configparser.ConfigParser:
    cp = configparser.ConfigParser()
    cp.read(CFG, encoding="utf-8")
    return cp


def _module_sections(cp: configparser.ConfigParser) -> list[tuple[set[str], configparser.SectionProxy]]:
    out = []
    for name in cp.sections():
        if name.startswith("mypy-"):
            out.append(({p.strip() for p in name[len("mypy-"):].split(",")}, cp[name]))
    return out


def _strict_modules(cp: configparser.ConfigParser) -> set[str]:
    mods: set[str] = set()
    for pats, sec in _module_sections(cp):
        if sec.get("disallow_untyped_defs", "False") == "True":
            mods |= pats
    return mods


def core_modules(core: Path = CORE) -> set[str]:
    """Dotted names of every module under ``core`` (``pkg/__init__.py`` is the package ``pkg``)."""
    root = core.parents[1]
    out = set()
    for path in core.rglob("*.py"):
        rel = path.relative_to(root).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        out.add(".".join(parts))
    return out


def _module_exists(mod: str) -> bool:
    rel = Path(*mod.removesuffix(".*").split("."))
    return (ROOT / rel.with_suffix(".py")).is_file() or (ROOT / rel / "__init__.py").is_file()


def test_mypy_config_only_gets_stricter():
    cp = _config()
    assert cp.has_section("mypy"), "setup.cfg: no [mypy] section"
    glob = cp["mypy"]
    for key in ("ignore_missing_imports", "ignore_errors", "follow_imports"):
        assert key not in glob, f"setup.cfg [mypy]: {key} must be set per module, not globally"
    assert glob.get("warn_redundant_casts") == "True"
    strict = _strict_modules(cp)
    assert STRICT_FLOOR <= strict, f"modules dropped from the strict section: {sorted(STRICT_FLOOR - strict)}"
    for pats, sec in _module_sections(cp):
        if pats & strict:
            for flag, value in STRICT_FLAGS.items():
                assert sec.get(flag) == value, f"setup.cfg [mypy-{','.join(sorted(pats))}]: {flag} must be {value}"
        for key in ("ignore_errors",):
            if sec.get(key) == "True":
                extra = pats - EXEMPT_CEILING
                assert not extra, f"new mypy exemptions are not allowed: {sorted(extra)}"
                assert not pats & strict
    for mod in strict:
        assert "*" not in mod, f"strict section: list modules explicitly, not {mod}"
        assert _module_exists(mod), f"strict section names a module that does not exist: {mod}"


def test_every_core_module_is_strict():
    strict = _strict_modules(_config())
    missing = sorted(core_modules() - strict)
    assert not missing, ("core modules missing from the strict section of setup.cfg (add them to "
                         "[mypy-piezo_ff_ros.core,…]):\n" + "\n".join(missing))


def test_core_modules_sees_every_module(tmp_path):
    """The checker itself: packages, nested packages and plain modules are all found."""
    core = tmp_path / "pkg" / "core"
    (core / "sub").mkdir(parents=True)
    for rel in ("__init__.py", "a.py", "sub/__init__.py", "sub/b.py"):
        (core / rel).write_text("")
    assert core_modules(core) == {"pkg.core", "pkg.core.a", "pkg.core.sub", "pkg.core.sub.b"}


def test_type_ignores_carry_a_reason():
    bad = []
    for path in sorted(CORE.rglob("*.py")):
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            m = re.search(r"#\s*type:\s*ignore(\[[^\]]*\])?(.*)$", line)
            if m and (not m.group(1) or not re.match(r"\s*#\s*\S", m.group(2))):
                bad.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not bad, "a `# type: ignore[code]` needs an error code and a `# reason` after it:\n" + "\n".join(bad)


def test_mypy_passes_on_core():
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed in this interpreter (requirements.txt pins it)")
    # a cache of its own: test_typing_commands runs mypy with --follow-imports=silent, and mypy's cache entries
    # depend on the options — one shared directory made each run invalidate the other's, both checked from scratch
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(CFG), "--cache-dir", str(ROOT / ".mypy_cache" / "core"),
           "piezo_ff_ros/core"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, f"mypy failed ({' '.join(cmd[1:])}):\n{out.stdout}{out.stderr}"
    assert "Success" in out.stdout, out.stdout + out.stderr
