"""Type checking gate for the command, node and ROS-process layers: mypy's default check, configured
in setup.cfg, passes on ``piezo_ff_ros/cli``, ``piezo_ff_ros/ros`` and ``piezo_ff_ros/nodes`` (with its backends),
and every function there is fully annotated.

PENDING holds files not checked yet (it may only shrink; empty since ``cli/bench.py`` and ``cli/diagnose.py`` were
annotated).
"""
from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "setup.cfg"
LAYERS = ("piezo_ff_ros/cli", "piezo_ff_ros/ros", "piezo_ff_ros/nodes", "piezo_ff_ros/backends")
PENDING: set[str] = set()   # empty now: every command module is annotated


def _files() -> list[Path]:
    return [p for layer in LAYERS for p in sorted((ROOT / layer).glob("*.py"))
            if p.relative_to(ROOT).as_posix() not in PENDING]


def _unannotated(path: Path) -> list[str]:
    out = []
    for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = n.args
            params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *(x for x in (a.vararg, a.kwarg) if x)]
            if n.returns is None or any(p.annotation is None for p in params if p.arg not in ("self", "cls")):
                out.append(f"{path.relative_to(ROOT)}:{n.lineno}: {n.name}")
    return out


def test_every_function_is_annotated():
    missing = [m for p in _files() for m in _unannotated(p)]
    assert not missing, "functions without full annotations:\n" + "\n".join(missing)


def test_pending_list_only_shrinks():
    for rel in PENDING:
        path = ROOT / rel
        if path.exists():
            assert _unannotated(path), f"{rel} is fully annotated now: remove it from PENDING (and check it)"


def test_mypy_passes_on_commands():
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed in this interpreter (requirements.txt pins it)")
    files = [str(p.relative_to(ROOT)) for p in _files()]
    # a cache of its own (its --follow-imports=silent entries would invalidate test_typing's strict ones, and back)
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(CFG),
           "--cache-dir", str(ROOT / ".mypy_cache" / "commands"),
           "--follow-imports=silent", *files]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, f"mypy failed:\n{out.stdout}{out.stderr}"
