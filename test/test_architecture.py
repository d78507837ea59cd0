"""The package's layering: which module may import which.

- the core never imports rclpy (every module under piezo_ff_ros/core imports in a process where rclpy is absent);
- no import cycle in the package, imports inside functions included;
- the compiled kernels import only the JIT helper (and each other);
- the configuration imports nothing above the units: only modules that import nothing of the package themselves;
- the core never imports the nodes, the ROS launchers, the CLI or the hardware backends;
- the hardware backends never import rclpy, the nodes, the ROS launchers or the CLI, and the CLI never imports the
  nodes (a command reaches ROS through ``ros/``);
- the CLI and the ROS launchers never import a private (``_name``) module or name of the core.

The import graph is read from the source (``ast``), so an import inside a function counts like one at the top.
"""
from __future__ import annotations

import ast
import re
import pkgutil
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = "piezo_ff_ros"

# Cycles whose owners are breaking them on their own branches; the strict test below refuses any other cycle now,
# the full one passes once those branches are merged.
PENDING_CYCLES: dict[frozenset[str], str] = {}   # none: every cycle is broken; keep it so


@dataclass(frozen=True)
class Import:
    """One import statement's target inside the package."""

    importer: str      #: the importing module
    module: str        #: the imported module (the longest package module the dotted name starts with)
    names: tuple[str, ...]  #: the names taken from it (``from m import a, b``); empty for ``import m``
    line: int

    def __str__(self) -> str:
        what = f" ({', '.join(self.names)})" if self.names else ""
        return f"{self.importer}:{self.line} imports {self.module}{what}"


@lru_cache(maxsize=1)
def modules() -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its ``__init__``)."""
    out = {}
    for p in sorted((ROOT / PKG).rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _owner(dotted: str, mods: dict[str, Path]) -> str | None:
    """The package module a dotted name lives in (``a.b.c`` → ``a.b`` when ``c`` is a name of ``a.b``)."""
    while dotted and dotted not in mods:
        dotted = dotted.rpartition(".")[0]
    return dotted or None


@lru_cache(maxsize=1)
def imports() -> tuple[Import, ...]:
    """Every import of a package module by a package module, at any depth of the source (functions included)."""
    mods = modules()
    out = []
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [(a.name, ()) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # ``from pkg import sub`` imports the module pkg.sub; ``from mod import name`` a name of mod
                targets = []
                for a in node.names:
                    sub = f"{mod}.{a.name}"
                    targets.append((sub, ()) if sub in mods else (mod, (a.name,)))
            else:
                continue
            for dotted, names in targets:
                if not dotted.startswith(PKG):
                    continue
                owner = _owner(dotted, mods)
                if owner is None or owner == name:
                    continue
                out.append(Import(name, owner, tuple(names), node.lineno))
    return tuple(out)


def cycles() -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan), imports of a module's own parent
    package left out (a package's ``__init__`` runs before any of its modules: that is not a cycle of ours)."""
    edges: dict[str, set[str]] = {m: set() for m in modules()}
    for imp in imports():
        if not imp.importer.startswith(imp.module + "."):
            edges[imp.importer].add(imp.module)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(frozenset(comp))
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def _within(module: str, area: str) -> bool:
    return module == area or module.startswith(area + ".")


def _describe(bad: list[Import]) -> str:
    return "\n".join(str(b) for b in bad)


# ------------------------------------------------------------------------------------------------------------------
# the graph reader itself: it must see what the rules are about, or every rule passes
# ------------------------------------------------------------------------------------------------------------------

def test_the_graph_reader_sees_top_level_relative_and_function_level_imports():
    by_importer = {(i.importer, i.module) for i in imports()}
    assert ("piezo_ff_ros.core.chain", "piezo_ff_ros.core.kernels.fused") in by_importer          # relative, top
    assert ("piezo_ff_ros.core.recording", "piezo_ff_ros.core.recording.mcap_reader") in by_importer  # in a function
    names = {n for i in imports() if i.importer == "piezo_ff_ros.core.chain" for n in i.names}
    assert {"FusedPart", "fused_layout"} <= names
    assert len(modules()) > 100


def test_the_cycle_finder_finds_a_cycle(monkeypatch):
    fake = (Import("piezo_ff_ros.a", "piezo_ff_ros.b", (), 1), Import("piezo_ff_ros.b", "piezo_ff_ros.a", (), 1))
    monkeypatch.setattr(sys.modules[__name__], "imports", lambda: fake)
    monkeypatch.setattr(sys.modules[__name__], "modules", lambda: {"piezo_ff_ros.a": ROOT, "piezo_ff_ros.b": ROOT})
    assert cycles() == [frozenset({"piezo_ff_ros.a", "piezo_ff_ros.b"})]


# ------------------------------------------------------------------------------------------------------------------
# the rules
# ------------------------------------------------------------------------------------------------------------------

def test_no_import_cycle_other_than_those_being_broken():
    new = [sorted(c) for c in cycles() if c not in PENDING_CYCLES]
    assert not new, f"import cycles: {new}"


def test_no_import_cycle():
    found = [sorted(c) for c in cycles()]
    assert not found, f"import cycles: {found}"


def test_kernels_import_only_the_jit_helper():
    bad = [i for i in imports() if _within(i.importer, "piezo_ff_ros.core.kernels")
           and not (_within(i.module, "piezo_ff_ros.core.kernels") or i.module == "piezo_ff_ros.core._jit")]
    assert not bad, _describe(bad)


def test_config_imports_nothing_above_the_units():
    """The configuration may import only leaf modules (``core.units``, ``core.transfer``: modules that import
    nothing of the package) and itself."""
    all_imports = imports()
    leaves = {m for m in modules() if not any(i.importer == m for i in all_imports)}
    assert {"piezo_ff_ros.core.units", "piezo_ff_ros.core.transfer"} <= leaves
    bad = [i for i in all_imports if _within(i.importer, "piezo_ff_ros.core.config")
           and not (_within(i.module, "piezo_ff_ros.core.config") or i.module in leaves)]
    assert not bad, _describe(bad)


@pytest.mark.parametrize("area", ["piezo_ff_ros.nodes", "piezo_ff_ros.ros", "piezo_ff_ros.cli",
                                  "piezo_ff_ros.backends"])
def test_core_never_imports_the_outer_layers(area):
    bad = [i for i in imports() if _within(i.importer, "piezo_ff_ros.core") and _within(i.module, area)]
    assert not bad, _describe(bad)


def test_the_cli_never_imports_the_nodes():
    bad = [i for i in imports() if _within(i.importer, "piezo_ff_ros.cli") and _within(i.module, "piezo_ff_ros.nodes")]
    assert not bad, _describe(bad)


def test_backends_import_neither_rclpy_nor_the_outer_layers():
    bad = [str(i) for i in imports() if _within(i.importer, "piezo_ff_ros.backends")
           and any(_within(i.module, a) for a in ("piezo_ff_ros.nodes", "piezo_ff_ros.ros", "piezo_ff_ros.cli"))]
    for name, path in modules().items():
        if _within(name, "piezo_ff_ros.backends"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                targets = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
                bad += [f"{name}:{node.lineno} imports {t}" for t in targets if t == "rclpy" or t.startswith("rclpy.")]
    assert not bad, "\n".join(bad)


def _private(imp: Import) -> bool:
    inner = imp.module.split(".")[1:]
    return any(part.startswith("_") and not part.startswith("__") for part in inner) or \
        any(n.startswith("_") for n in imp.names)


def test_private_means_an_underscore_module_or_name():
    assert _private(Import("piezo_ff_ros.cli.x", "piezo_ff_ros.core._jit", (), 1))
    assert _private(Import("piezo_ff_ros.cli.x", "piezo_ff_ros.core.tracking.benchmark", ("run", "_private_helper"), 1))
    assert not _private(Import("piezo_ff_ros.cli.x", "piezo_ff_ros.core.recording", ("load_run",), 1))


PRIVATE_PENDING: dict[str, str] = {}   # none any more


@pytest.mark.parametrize("area", ["piezo_ff_ros.cli", "piezo_ff_ros.ros"])
def test_cli_and_ros_never_import_private_names_of_the_core(area):
    bad = [i for i in imports() if _within(i.importer, area) and _within(i.module, "piezo_ff_ros.core")
           and _private(i) and i.importer not in PRIVATE_PENDING]
    assert not bad, _describe(bad)


def test_cli_imports_no_private_name_of_the_core_at_all():
    bad = [i for i in imports() if _within(i.importer, "piezo_ff_ros.cli") and _within(i.module, "piezo_ff_ros.core")
           and _private(i)]
    assert not bad, _describe(bad)


def test_core_imports_without_rclpy():
    import piezo_ff_ros.core as core

    names = [m.name for m in pkgutil.walk_packages(core.__path__, "piezo_ff_ros.core.")]
    assert len(names) > 30
    code = (
        "import importlib, sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'rclpy' or name.startswith('rclpy.'):\n"
        "            raise ImportError('rclpy is not allowed in the core')\n"
        "sys.meta_path.insert(0, Block())\n"
        f"for n in {names!r}:\n"
        "    importlib.import_module(n)\n"
        "assert not any(m == 'rclpy' or m.startswith('rclpy.') for m in sys.modules)\n"
        "print('ok', len(sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")


# Issue numbers mean nothing to a reader outside the team: a docstring or comment says what the code does or what a
# test checks.  The diagnosis paths are being edited on another branch (diag) and are checked once it is merged.
ISSUE_NUMBER = re.compile(r"\bissue[ -]?#?\d+", re.IGNORECASE)
ISSUE_NUMBER_PENDING: tuple[str, ...] = ()   # none left


def test_the_issue_number_pattern():
    word = "is" + "sue"   # spelt apart, or this file would hold what it refuses
    cases = {f"{word} 11": True, f"({word.title()} 20)": True, f"{word}-8": True, f"{word} #3": True,
             f"{word.upper()} 10.5": True, f"{word}s": False, f"t{word} 3": False, f"the {word} is 3 V": False}
    assert {s: bool(ISSUE_NUMBER.search(s)) for s in cases} == cases


def test_no_issue_number_in_package_test_or_bench_sources():
    hits = []
    for top in ("piezo_ff_ros", "test", "bench"):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith(ISSUE_NUMBER_PENDING):
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                m = ISSUE_NUMBER.search(line)
                if m:
                    hits.append(f"{rel}:{n}: {m.group(0)}")
    assert not hits, "issue numbers in sources (say what the code does or the test checks):\n" + "\n".join(hits)
