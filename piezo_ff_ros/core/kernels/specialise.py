"""Modal-bank loops specialised to one bank's structure: generated source, compiled and cached by numba (pure).

A two-axis modal bank (:func:`~.modal.pad_to_2x2`: a ``[12, blocks]`` coefficient table) spends most of its time
loading coefficients and multiplying by the zeros the padding puts in: a 1×1 block padded to 2×2, a block of one
transfer entry that reaches one output from one input.  The generic loop (:func:`~.modal.bank2_loop`) cannot skip
them without branching per block.  For a given *structure* — the block sizes and which coefficients are non-zero —
this module writes the loop out as straight-line code that holds the state in local variables, reads each non-zero
coefficient once per block of samples and leaves every zero term out.  Every sum keeps the generic loop's order
(state by state, then the inputs) and the terms left out are exact zeros, so the numbers are the generic loop's
(``test/test_kernels_specialised.py`` compares them with ``array_equal``).

Coefficient *values* are arguments: a bank whose numbers change but whose structure does not (a new controller of
the same order, a re-identified model) reuses the compiled loop.  Each structure's source is written once to a
cache directory (content-addressed file name) and imported from there, so numba's on-disk cache applies to it as to
any module: the first use of a structure compiles (≈ 1–2 s), later processes load it.

``PIEZO_FF_SPECIALISE=0`` turns specialisation off (the generic loops run; same numbers); ``PIEZO_FF_KERNEL_CACHE``
chooses the directory (default: ``$XDG_CACHE_HOME/piezo_ff_ros/kernels``, else ``~/.cache/…``, else a temporary
directory).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

import numpy as np

__all__ = ["enabled", "cache_dir", "bank_structure", "bank_loop_source", "inverse_loop_source",
           "specialised_bank_run", "specialised_inverse_run", "load_generated", "generated_kernels",
           "bank_loop_module", "inverse_loop_module"]

#: rows of the coefficient table (see :mod:`.modal`)
_A_PP, _A_PQ, _A_QP, _A_QQ, _B_P0, _B_P1, _B_Q0, _B_Q1, _C_0P, _C_0Q, _C_1P, _C_1Q = range(12)

_lock = threading.Lock()
_modules: dict[str, ModuleType] = {}
#: the loop module of each (kind, structure) already loaded: a plant or compensator is rebuilt many times over (every
#: trial of a diagnosis fit), and writing its loop's source afresh only to find the module loaded costs ~0.5 ms
_by_structure: dict[tuple[str, Any], ModuleType] = {}


def enabled() -> bool:
    """True unless ``PIEZO_FF_SPECIALISE`` is set to ``0``/``false``/``no``/``off``."""
    return os.environ.get("PIEZO_FF_SPECIALISE", "1").strip().lower() not in ("0", "false", "no", "off")


def cache_dir() -> Path:
    """The directory generated kernels are written to (created if needed; see the module docstring)."""
    env = os.environ.get("PIEZO_FF_KERNEL_CACHE")
    candidates: list[Path] = []
    if env:
        candidates.append(Path(env))
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg:
        candidates.append(Path(xdg) / "piezo_ff_ros" / "kernels")
    candidates.append(Path.home() / ".cache" / "piezo_ff_ros" / "kernels")
    candidates.append(Path(tempfile.gettempdir()) / f"piezo_ff_ros-kernels-{os.getuid() if hasattr(os, 'getuid') else 0}")
    for c in candidates:
        try:
            c.mkdir(parents=True, exist_ok=True)
            if os.access(c, os.W_OK):
                return c
        except OSError:
            continue
    raise OSError("no writable directory for generated kernels (set PIEZO_FF_KERNEL_CACHE)")


def bank_structure(W: np.ndarray, sizes: np.ndarray, D: np.ndarray) -> tuple[tuple[int, ...], tuple[bool, ...],
                                                                               tuple[bool, ...]]:
    """The structure a specialised loop depends on: block sizes, non-zero pattern of ``W`` [12, blocks] and of
    ``D`` [2, 2] (row-major).

    Parameters
    ----------
    W : ndarray
        Coefficient table from :func:`~.modal.pad_to_2x2`.
    sizes : ndarray
        Block sizes (1 or 2).
    D : ndarray
        Feedthrough (``K⁻¹`` for the creep compensator), 2×2.

    Returns
    -------
    tuple
        ``(sizes, W != 0 row-major, D != 0 row-major)`` as plain tuples (hashable).
    """
    Wa = np.asarray(W, float)
    return (tuple(int(s) for s in sizes), tuple(bool(v) for v in (Wa != 0.0).reshape(-1)),
            tuple(bool(v) for v in (np.asarray(D, float) != 0.0).reshape(-1)))


def _fold(terms: list[str]) -> str:
    """``terms`` summed left to right (the generic loop's order), ``0.0`` when empty."""
    if not terms:
        return "0.0"
    expr = terms[0]
    for t in terms[1:]:
        expr = f"({expr} + {t})"
    return expr


class _Bank:
    """Names and expressions of one bank's straight-line code."""

    def __init__(self, structure: tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]]) -> None:
        sizes, wmask, dmask = structure
        self.sizes = sizes
        self.nb = len(sizes)
        self.offsets = [int(v) for v in np.concatenate([[0], np.cumsum(sizes)[:-1]])] if sizes else []
        self._w = np.array(wmask, bool).reshape(12, self.nb) if self.nb else np.zeros((12, 0), bool)
        self._d = np.array(dmask, bool).reshape(2, 2)

    def nz(self, row: int, b: int) -> bool:
        return bool(self._w[row, b])

    def two(self, b: int) -> bool:
        return self.sizes[b] == 2

    def load_lines(self, indent: str, coeffs: str = "W") -> list[str]:
        """Non-zero coefficients and the state (public layout ``x``: block b at ``offsets[b]``) into locals."""
        out = []
        for b in range(self.nb):
            for r in range(12):
                if self.nz(r, b):
                    out.append(f"{indent}w{r}_{b} = {coeffs}[{r}, {b}]")
            out.append(f"{indent}p{b} = x[{self.offsets[b]}]")
            if self.two(b):
                out.append(f"{indent}q{b} = x[{self.offsets[b] + 1}]")
        return out

    def store_lines(self, indent: str) -> list[str]:
        out = []
        for b in range(self.nb):
            out.append(f"{indent}x[{self.offsets[b]}] = p{b}")
            if self.two(b):
                out.append(f"{indent}x[{self.offsets[b] + 1}] = q{b}")
        return out

    def output_expr(self, o: int) -> str:
        """``C x`` for output ``o`` in the generic order (block by block, p then q)."""
        rp, rq = (_C_0P, _C_0Q) if o == 0 else (_C_1P, _C_1Q)
        terms = []
        for b in range(self.nb):
            if self.nz(rp, b):
                terms.append(f"w{rp}_{b} * p{b}")
            if self.two(b) and self.nz(rq, b):
                terms.append(f"w{rq}_{b} * q{b}")
        return _fold(terms)

    def update_lines(self, indent: str, u0: str, u1: str) -> list[str]:
        """``x ← A x + B u`` (new values into ``np…``/``nq…``, then assigned), generic order."""
        out = []
        for b in range(self.nb):
            rows = [("p", _A_PP, _A_PQ, _B_P0, _B_P1)]
            if self.two(b):
                rows.append(("q", _A_QP, _A_QQ, _B_Q0, _B_Q1))
            for name, ra, rb, r0, r1 in rows:
                terms = []
                if self.nz(ra, b):
                    terms.append(f"w{ra}_{b} * p{b}")
                if self.two(b) and self.nz(rb, b):
                    terms.append(f"w{rb}_{b} * q{b}")
                if self.nz(r0, b):
                    terms.append(f"w{r0}_{b} * {u0}")
                if self.nz(r1, b):
                    terms.append(f"w{r1}_{b} * {u1}")
                out.append(f"{indent}n{name}{b} = {_fold(terms)}")
        for b in range(self.nb):
            out.append(f"{indent}p{b} = np{b}")
            if self.two(b):
                out.append(f"{indent}q{b} = nq{b}")
        return out

    def feedthrough(self, o: int, y: str, u0: str, u1: str) -> str:
        """``y + D[o, 0] u0 + D[o, 1] u1`` in the generic order, zero terms left out."""
        expr = y
        for j, u in ((0, u0), (1, u1)):
            if self._d[o, j]:
                expr = f"({expr} + d{o}{j} * {u})"
        return expr

    def d_lines(self, indent: str, name: str = "D") -> list[str]:
        return [f"{indent}d{o}{j} = {name}[{o}, {j}]" for o in range(2) for j in range(2) if self._d[o, j]]


def _kernel_fingerprint(here: Path | None = None) -> str:
    """A digest of the kernel sources a generated module calls into (``here``: the kernels' directory).

    numba's on-disk cache of a function is keyed on its own file only, not on the functions it calls; the digest
    goes into every generated source (hence into its content-addressed file name), so a changed kernel gives new
    files instead of stale compiled code.
    """
    here = here or Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted([*here.glob("*.py"), here.parent / "_jit.py"]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


_HEADER = f'''"""Generated by piezo_ff_ros.core.kernels.specialise — do not edit (content-addressed, rewritten on demand).

Kernel sources: {_kernel_fingerprint()}
"""
from piezo_ff_ros.core._jit import njit

'''


def bank_loop_source(structure: tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]],
                     name: str = "bank_loop") -> str:
    """Source of a loop with :func:`~.modal.bank2_loop`'s numbers for one bank structure.

    Parameters
    ----------
    structure : tuple
        From :func:`bank_structure`.
    name : str
        The function's name.

    Returns
    -------
    str
        Python source defining ``name(W, D, x, src, dst, n)``: ``n`` samples of ``src`` through the bank
        (coefficient table ``W`` [12, blocks], feedthrough ``D``) into ``dst`` (may be ``src``), the state ``x`` in
        its public layout (:meth:`~piezo_ff_ros.core.lti.DiscreteModalSS.packed` offsets) carried.
    """
    bk = _Bank(structure)
    L = ["@njit", f"def {name}(W, D, x, src, dst, n):  # pragma: no cover - compiled"]
    L += bk.load_lines("    ") + bk.d_lines("    ")
    L.append("    for k in range(n):")
    L.append("        u0 = src[k, 0]")
    L.append("        u1 = src[k, 1]")
    L.append(f"        y0 = {bk.output_expr(0)}")
    L.append(f"        y1 = {bk.output_expr(1)}")
    L += bk.update_lines("        ", "u0", "u1")
    L.append(f"        dst[k, 0] = {bk.feedthrough(0, 'y0', 'u0', 'u1')}")
    L.append(f"        dst[k, 1] = {bk.feedthrough(1, 'y1', 'u0', 'u1')}")
    L += bk.store_lines("    ")
    return "\n".join(L) + "\n"


def inverse_loop_source(structure: tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]],
                        name: str = "inverse_loop") -> str:
    """Source of a loop with :func:`~.modal.inverse2_loop`'s numbers (the creep compensator's
    ``Y_H = K⁻¹(Y_L − C x)``, ``x ← A x + B Y_H``) for one bank structure (``D`` in the structure is ``K⁻¹``).

    Parameters
    ----------
    structure : tuple
        From :func:`bank_structure` with ``K⁻¹`` as ``D``.
    name : str
        The function's name.

    Returns
    -------
    str
        Python source defining ``name(Kinv, W, x, src, dst, n)`` (state ``x`` in its public layout).
    """
    bk = _Bank(structure)
    L = ["@njit", f"def {name}(Kinv, W, x, src, dst, n):  # pragma: no cover - compiled"]
    L += bk.load_lines("    ") + bk.d_lines("    ", "Kinv")
    L.append("    for k in range(n):")
    L.append(f"        c0 = src[k, 0] - {bk.output_expr(0)}")
    L.append(f"        c1 = src[k, 1] - {bk.output_expr(1)}")
    for o in range(2):
        terms = [f"d{o}{j} * c{j}" for j in range(2) if bk._d[o, j]]
        L.append(f"        v{o} = {_fold(terms)}")
    L += bk.update_lines("        ", "v0", "v1")
    L.append("        dst[k, 0] = v0")
    L.append("        dst[k, 1] = v1")
    L += bk.store_lines("    ")
    return "\n".join(L) + "\n"


def load_generated(source: str, stem: str) -> ModuleType:
    """Import generated ``source`` as a module from the kernel cache directory (written once, content-addressed).

    Parameters
    ----------
    source : str
        Module source (without the header, which is added).
    stem : str
        File-name prefix (``<stem>_<hash>.py``).

    Returns
    -------
    module
        The imported module (one per source per process).
    """
    text = _HEADER + source
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    modname = f"piezo_ff_ros_generated_{stem}_{digest}"
    with _lock:
        mod = _modules.get(modname)
        if mod is not None:
            return mod
        path = cache_dir() / f"{stem}_{digest}.py"
        if not path.exists() or path.read_text() != text:
            # write beside, then rename: another process may be importing the same file right now
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{stem}_", suffix=".py")
            with os.fdopen(fd, "w") as f:
                f.write(text)
            os.replace(tmp, path)
        spec = importlib.util.spec_from_file_location(modname, path)
        if spec is None or spec.loader is None:  # pragma: no cover - a .py path always has a loader
            raise ImportError(f"cannot import generated kernel {path}")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[modname] = mod
        spec.loader.exec_module(mod)
        _modules[modname] = mod
        return mod


_BANK_RUN = """
@njit
def bank_run(W, offsets, sizes, feeds, D, x, u, y):  # pragma: no cover - compiled
    bank_loop(W, D, x, u, y, u.shape[0])
"""

_INVERSE_RUN = """
@njit
def inverse_run(Kinv, W, offsets, sizes, feeds, x, yl, yh):  # pragma: no cover - compiled
    inverse_loop(Kinv, W, x, yl, yh, yl.shape[0])
"""


def bank_loop_module(W: np.ndarray, sizes: np.ndarray, D: np.ndarray) -> ModuleType:
    """The generated module holding this bank structure's ``bank_loop`` (:func:`bank_loop_source`), shared by the
    stage's own run and every fused pass it joins (compiled once).

    Parameters
    ----------
    W, sizes, D : ndarray
        The bank (:func:`~.modal.pad_to_2x2`), its block sizes and feedthrough.

    Returns
    -------
    module
        Imported (and registered in ``sys.modules``) under its content-addressed name.
    """
    return _structure_module("bankloop", bank_structure(W, sizes, D), bank_loop_source)


def inverse_loop_module(Kinv: np.ndarray, W: np.ndarray, sizes: np.ndarray) -> ModuleType:
    """The generated module holding this creep compensator structure's ``inverse_loop``
    (:func:`inverse_loop_source`), shared like :func:`bank_loop_module`.

    Parameters
    ----------
    Kinv, W, sizes : ndarray
        ``K⁻¹``, the bank (:func:`~.modal.pad_to_2x2`) and its block sizes.

    Returns
    -------
    module
    """
    return _structure_module("inverseloop", bank_structure(W, sizes, Kinv), inverse_loop_source)


def _structure_module(stem: str, structure: tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]],
                      source: Callable[[tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]]], str]
                      ) -> ModuleType:
    """The generated module of ``source(structure)`` (:func:`load_generated`), its source written only the first
    time this process asks for the structure."""
    key = (stem, structure)
    mod = _by_structure.get(key)
    if mod is None:
        mod = load_generated(source(structure), stem)
        _by_structure[key] = mod
    return mod


def generated_kernels() -> dict[str, Any]:
    """The compiled functions of every generated module loaded in this process, by ``<stem>_<hash>.<name>``.

    Returns
    -------
    dict
        Name → numba dispatcher (or plain function without numba).
    """
    out: dict[str, Any] = {}
    with _lock:
        for modname, mod in _modules.items():
            short = modname.removeprefix("piezo_ff_ros_generated_")
            for name, obj in vars(mod).items():
                if getattr(obj, "__module__", None) == modname and hasattr(obj, "py_func"):
                    out[f"{short}.{name}"] = obj
    return out


def specialised_bank_run(W: np.ndarray, sizes: np.ndarray, D: np.ndarray) -> Callable[..., None] | None:
    """This bank's compiled run (signature of :func:`~.modal.bank_run_2x2`), or None when specialisation is off.

    Parameters
    ----------
    W, sizes, D : ndarray
        The bank (:func:`~.modal.pad_to_2x2`), its block sizes and feedthrough.

    Returns
    -------
    callable or None
        ``run(W, offsets, sizes, feeds, D, x, u, y)``: the block ``u`` through the bank, state ``x`` (public
        layout) carried.
    """
    if not enabled():
        return None
    loop = bank_loop_module(W, sizes, D)
    src = f"from {loop.__name__} import bank_loop\n" + _BANK_RUN
    fn: Callable[..., None] = load_generated(src, "bank").bank_run
    return fn


def specialised_inverse_run(Kinv: np.ndarray, W: np.ndarray, sizes: np.ndarray) -> Callable[..., None] | None:
    """This creep compensator's compiled run (signature of :func:`~.modal.inverse_affine_run_2x2`), or None when
    specialisation is off.

    Parameters
    ----------
    Kinv, W, sizes : ndarray
        ``K⁻¹``, the bank (:func:`~.modal.pad_to_2x2`) and its block sizes.

    Returns
    -------
    callable or None
        ``run(Kinv, W, offsets, sizes, feeds, x, yl, yh)``.
    """
    if not enabled():
        return None
    loop = inverse_loop_module(Kinv, W, sizes)
    src = f"from {loop.__name__} import inverse_loop\n" + _INVERSE_RUN
    fn: Callable[..., None] = load_generated(src, "inverse").inverse_run
    return fn
