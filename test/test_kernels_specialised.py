"""Bank loops specialised to a bank's structure (core/kernels/specialise.py): the generic kernels' numbers, bit for
bit, on random structures and block splits; the fused chain gives the same numbers with specialisation on or off;
the generated sources are cached by content."""
from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from piezo_ff_ros.core.chain import Chain
from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.compensators.creep import CreepCompensator
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.kernels import modal as km
from piezo_ff_ros.core.kernels import specialise as sp
from piezo_ff_ros.core.lti import DiscreteModalSS, LTIFilter
from piezo_ff_ros.core.models.plant import Plant

DT = 1 / 20000.0
# test_chain.py's 4th-order 2×2 stand-in for C(s) (real and complex modes, D ≠ 0)
STAND_IN_C = (np.array([[-300.0, 0, 0, 0], [0, -2000.0, 0, 0], [0, 0, -500.0, 4000.0], [0, 0, -4000.0, -500.0]]),
              np.array([[300.0, 0.0], [0.0, 2000.0], [100.0, 50.0], [0.0, 80.0]]),
              np.array([[0.2, 0.0, 0.1, 0.05], [0.0, 0.1, 0.02, 0.1]]), np.array([[0.9, 0.01], [0.02, 0.85]]))


def _random_ss(seed: int, siso: bool, feedthrough: bool, strictly_proper: bool = False) -> DiscreteModalSS:
    """A random stable 2-input 2-output modal system: real and complex modes; ``siso``: every mode reaches one
    output from one input (zeros in B and C, as a transfer matrix realised entry by entry)."""
    rng = np.random.default_rng(seed)
    n_real, n_cplx = int(rng.integers(0, 4)), int(rng.integers(0, 4))
    poles = list(-rng.uniform(5, 3000, n_real))
    A = np.zeros((n_real + 2 * n_cplx,) * 2)
    A[:n_real, :n_real] = np.diag(poles)
    for i in range(n_cplx):
        o = n_real + 2 * i
        s, w = -rng.uniform(20, 800), rng.uniform(100, 8000)
        A[o:o + 2, o:o + 2] = [[s, w], [-w, s]]
    n = A.shape[0]
    B = rng.standard_normal((n, 2)) * 100
    C = rng.standard_normal((2, n))
    if siso:
        blocks = [[i] for i in range(n_real)] + [[n_real + 2 * i, n_real + 2 * i + 1] for i in range(n_cplx)]
        for idx in blocks:
            j, o = rng.integers(0, 2, size=2)
            B[idx, 1 - j] = 0.0
            C[1 - o, idx] = 0.0
    D = rng.standard_normal((2, 2)) if feedthrough and not strictly_proper else np.zeros((2, 2))
    if feedthrough and not strictly_proper and rng.random() < 0.5:
        D[0, 1] = 0.0
    return DiscreteModalSS.zoh_from_ss(A, B, C, D, DT)


def _signal(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    return np.ascontiguousarray(np.column_stack([np.sin(2 * np.pi * 37 * t), np.cos(2 * np.pi * 410 * t)])
                                + 0.1 * rng.standard_normal((n, 2)))


def _pieces(x: np.ndarray, seed: int) -> list[np.ndarray]:
    cuts = np.sort(np.random.default_rng(seed).integers(0, len(x), size=5))
    return np.split(x, cuts)


@pytest.mark.parametrize("seed,siso,feedthrough", [(1, True, False), (2, False, True), (3, True, True),
                                                   (4, False, False), (5, True, True)])
def test_specialised_bank_is_the_generic_kernel_bit_for_bit(seed, siso, feedthrough):
    ss = _random_ss(seed, siso, feedthrough)
    filt = LTIFilter(ss)
    assert filt.two_axis
    u = _signal(2500, seed)
    fast = np.vstack([filt.process(p) for p in _pieces(u, seed)])
    assert filt._run is not km.bank_run_2x2  # the specialised loop ran
    Ablk, offsets = ss.packed()
    x = np.zeros(ss.n_states)
    ref = np.empty_like(fast)
    km.bank_run(Ablk, offsets, ss.sizes, ss.B, ss.C, ss.D, x, u, ref)
    assert np.array_equal(fast, ref) and np.array_equal(filt.x, x)


def test_a_bank_without_states_is_its_feedthrough():
    ss = DiscreteModalSS.zoh_from_ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)),
                                     np.array([[0.5, 0.0], [0.1, 2.0]]), DT)
    u = _signal(300, 0)
    filt = LTIFilter(ss)
    assert filt.two_axis
    y = filt.process(u)
    Ablk, offsets = ss.packed()
    ref = np.empty_like(y)
    km.bank_run(Ablk, offsets, ss.sizes, ss.B, ss.C, ss.D, np.zeros(0), u, ref)
    assert np.array_equal(y, ref) and np.allclose(y[:, 0], 0.5 * u[:, 0])


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_specialised_creep_inverse_is_the_generic_kernel_bit_for_bit(seed):
    cfg = load_config()
    comp = CreepCompensator(cfg.creep, cfg.dt)
    ss = _random_ss(seed, siso=seed != 12, feedthrough=False, strictly_proper=True)
    # the compensator on a random strictly proper Cr (same K): swap its bank in
    comp.ss = ss
    comp._Ablk, comp._offsets = ss.packed()
    comp.W, comp.feeds = km.pad_to_2x2(comp._Ablk, ss.packed_io(), comp._offsets, ss.sizes)
    comp.x = np.zeros(ss.n_states)
    comp._run = None
    yl = _signal(2000, seed) * 1e-5
    fast = np.vstack([comp.process(p) for p in _pieces(yl, seed)])
    x = np.zeros(ss.n_states)
    ref = np.empty_like(yl)
    km.inverse_affine_run(comp.Kinv, comp._Ablk, comp._offsets, ss.sizes, ss.B, ss.C, x, yl, ref)
    assert np.array_equal(fast, ref) and np.array_equal(comp.x, x)


def _flatten(state, prefix=()):
    out = {}
    for key, value in state.items():
        if isinstance(value, dict):
            out.update(_flatten(value, prefix + (key,)))
        else:
            out[prefix + (key,)] = value
    return out


def test_the_fused_chain_gives_the_same_numbers_with_or_without_specialisation(monkeypatch):
    cfg = load_config()
    cfg = replace(cfg, limits=replace(cfg.limits, voltage=80.0))
    k = STAND_IN_C   # the chain tests' stand-in C(s) (test_chain.py): its specialised kernels are compiled once

    def run(flag: str) -> tuple[np.ndarray, dict]:
        monkeypatch.setenv("PIEZO_FF_SPECIALISE", flag)
        chain = Chain([("cascade", CompensatorCascade(cfg, controller=k)), ("plant", Plant(cfg))])
        yr = _signal(3000, 5) * 10e-6
        y = np.vstack([chain.process(p) for p in _pieces(yr, 8)])
        return y, chain.state()
    y_on, s_on = run("1")
    y_off, s_off = run("0")
    assert np.array_equal(y_on, y_off)
    flat_on, flat_off = _flatten(s_on), _flatten(s_off)
    assert flat_on.keys() == flat_off.keys() and len(flat_on) >= 6
    for key in flat_on:
        assert np.array_equal(np.asarray(flat_on[key]), np.asarray(flat_off[key])), key


def test_switched_off_the_generic_loops_run(monkeypatch):
    monkeypatch.setenv("PIEZO_FF_SPECIALISE", "off")
    assert not sp.enabled()
    filt = LTIFilter(_random_ss(3, True, True))
    filt.process(_signal(10, 0))
    assert filt._run is km.bank_run_2x2


def test_zero_coefficients_are_left_out_of_the_generated_loop():
    ss = _random_ss(1, siso=True, feedthrough=False)
    filt = LTIFilter(ss)
    src = sp.bank_loop_source(sp.bank_structure(filt.W, ss.sizes, ss.D))
    loads = src.count("= W[")
    assert loads == int(np.count_nonzero(filt.W)) < 12 * len(ss.sizes)
    assert "d00" not in src  # D = 0: no feedthrough terms


def test_generated_sources_are_written_once_and_found_by_content(tmp_path, monkeypatch):
    monkeypatch.setenv("PIEZO_FF_KERNEL_CACHE", str(tmp_path))
    src = "\n@njit\ndef twice(x):  # pragma: no cover - compiled\n    return 2.0 * x\n"
    mod = sp.load_generated(src, "probe")
    files = sorted(tmp_path.glob("probe_*.py"))
    assert len(files) == 1 and mod.twice(3.0) == 6.0
    mtime = files[0].stat().st_mtime_ns
    assert sp.load_generated(src, "probe") is mod and files[0].stat().st_mtime_ns == mtime
    other = sp.load_generated(src.replace("2.0", "3.0"), "probe")
    assert other.twice(3.0) == 9.0 and len(list(tmp_path.glob("probe_*.py"))) == 2


def test_a_tampered_cache_file_is_rewritten(tmp_path, monkeypatch):
    monkeypatch.setenv("PIEZO_FF_KERNEL_CACHE", str(tmp_path))
    src = "\n@njit\ndef thrice(x):  # pragma: no cover - compiled\n    return 3.0 * x\n"
    text = sp._HEADER + src
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    (tmp_path / f"tamper_{digest}.py").write_text("def thrice(x):\n    return 0.0\n")
    mod = sp.load_generated(src, "tamper")
    assert mod.thrice(2.0) == 6.0


def test_an_unwritable_cache_setting_falls_back_to_a_writable_directory(tmp_path, monkeypatch):
    blocked = tmp_path / "file_not_dir"
    blocked.write_text("x")
    monkeypatch.setenv("PIEZO_FF_KERNEL_CACHE", str(blocked / "sub"))
    d = sp.cache_dir()
    assert d != blocked / "sub" and d.is_dir()


def test_a_changed_kernel_source_changes_every_generated_file_name(tmp_path):
    """numba caches a function on its own file only: the kernels' digest in the generated source keeps a cached
    fused pass from running the code of an older kernel."""
    import shutil
    from pathlib import Path
    kernels = Path(sp.__file__).resolve().parent
    copy = tmp_path / "kernels"
    shutil.copytree(kernels, copy, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(kernels.parent / "_jit.py", tmp_path / "_jit.py")
    before = sp._kernel_fingerprint(copy)
    assert before == sp._kernel_fingerprint(kernels) and before in sp._HEADER
    src = copy / "bouc_wen.py"
    src.write_text(src.read_text() + "\n# changed\n")
    assert sp._kernel_fingerprint(copy) != before
