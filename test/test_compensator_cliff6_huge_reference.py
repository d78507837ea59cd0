"""A huge reference (1 m, ±1e6 m, a 2e6 m step) through the compensator with ``reference_limit`` emptied: the work
per sample does not grow with the amplitude, the voltages are finite and what the model says, the result does not
depend on the block split, and a reference too large for any state to stay finite is refused with one line.

The work is counted, never timed (the machine is shared): the compensator core runs in a child process with numba's
JIT off, and every line executed inside the Bouc-Wen kernels (:mod:`piezo_ff_ros.core.kernels.bouc_wen`, where the
hysteresis inverse integrates its path) is counted with ``sys.settrace`` — a deterministic proxy for the compiled
kernel's work.  A run that goes over a generous budget is stopped there (the old kernel took ~1000× the work on a
1 m reference and ~1e6× on 1e6 m; it would run for hours in pure Python).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dataclasses

from piezo_ff_ros.core._jit import njit
from piezo_ff_ros.core.compensator_core import (ERROR, HARD_REFERENCE_FACTOR, CompensatorCore, CompensatorSettings,
                                                ParameterBook)
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
from piezo_ff_ros.core.kernels import bouc_wen as kb
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel
from piezo_ff_ros.core.param_map import config_to_params
from piezo_ff_ros.core.trajectories.workspace import reachable_range

ROOT = Path(__file__).resolve().parents[1]
N = 200
DT = 50_000
S0 = 1_000_000 * DT

#: the child process: one fresh core per case, an ordinary 2-sample block first (not counted), then the counted
#: block; prints {case: lines executed in the Bouc-Wen kernels per counted sample} (None: stopped at the budget)
_COUNT_SCRIPT = r"""
import json, sys
import numpy as np
from piezo_ff_ros.core.compensator_core import CompensatorCore, CompensatorSettings, ParameterBook
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.kernels import bouc_wen as kb
from piezo_ff_ros.core.param_map import config_to_params

CASES = json.loads(sys.argv[1])
BUDGET = int(sys.argv[2])
FILE = kb.__file__
base = load_config()


class OverBudget(Exception):
    pass


count = 0


def line(frame, event, arg):
    global count
    if event == "line":
        count += 1
        if count > BUDGET:
            raise OverBudget
    return line


def call(frame, event, arg):
    return line if frame.f_code.co_filename == FILE else None


out = {}
for name, rows in CASES.items():
    book = ParameterBook(base)
    book.values.update(config_to_params(base))
    book.values["cascade.vibration"] = False
    core = CompensatorCore(book, book.end_declarations(), CompensatorSettings(reference_limit=()))
    dt = 50_000
    s0 = 1_000_000 * dt
    core.on_reference(s0, np.tile([10e-6, -5e-6], (2, 1)), 0.0)
    block = np.array(rows, float)
    count = 0
    sys.settrace(call)
    try:
        em = core.on_reference(s0 + 2 * dt, block, 0.0)
        sys.settrace(None)
        u = em.voltage[0].u
        out[name] = {"lines": count / len(block), "finite": bool(np.all(np.isfinite(u))),
                     "max_abs_u": float(np.max(np.abs(u)))}
    except OverBudget:
        sys.settrace(None)
        out[name] = None
print(json.dumps(out))
"""


def _kernel_lines(cases: dict[str, list[list[float]]], budget: int) -> dict:
    env = dict(os.environ, NUMBA_DISABLE_JIT="1", PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-c", _COUNT_SCRIPT, json.dumps(cases), str(budget)], env=env,
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_kernel_work_per_sample_does_not_grow_with_the_reference_amplitude():
    """A reference 100 times out of range (1 mm: its voltage clamps at ±200 V while the inverse integrates a ~6 kV
    path) costs at most 40 samples of an ordinary one (a 10 µm move, itself an exact path with Newton steps); 1 m,
    ±1e6 m and a 2e6 m step within the block cost at most 3× the 1 mm work per sample; all give finite voltages
    within ±200 V."""
    held = lambda x, y, n=3: [[x, y]] * n  # noqa: E731
    cases = {"1 mm": held(1e-3, 0.0), "1 m": held(1.0, 0.0), "+1e6 m": held(1e6, 1e6), "-1e6 m": held(-1e6, 3e5),
             "2e6 m step": [[1e6, -1e6], [1e6, -1e6], [-1e6, 1e6], [-1e6, 1e6]]}
    ordinary = _kernel_lines({"10 um": held(12e-6, -4e-6)}, 10_000_000)["10 um"]
    assert ordinary is not None and ordinary["finite"]
    unit = ordinary["lines"]
    got = _kernel_lines(cases, int(60 * unit * 4))   # a case stopped at 60× (None) has failed already
    assert got["1 mm"] is not None and got["1 mm"]["lines"] <= 40 * unit, (got["1 mm"], unit)
    base = got["1 mm"]["lines"]
    over = {k: v for k, v in got.items() if v is None or v["lines"] > 3 * base}
    assert not over, f"work per sample beyond 3x that of a 1 mm reference ({base:.0f} lines): " \
                     f"{ {k: (v and v['lines']) for k, v in over.items()} }"
    for k, v in got.items():
        assert v["finite"] and v["max_abs_u"] <= 200.0, (k, v)


# ------------------------------------------------------------------------------------------------ compiled kernels


@pytest.fixture(scope="module")
def base():
    return load_config()


def _generalized(cfg):
    return dataclasses.replace(cfg, Delta1=((0.0012, 0.0001), (0.0, -0.0008)),
                               Delta2=((-0.0005, 0.0), (0.0001, 0.0007))).validate()


def _exact(cfg, h, du):
    p = kb.params_of(cfg.arrays())
    he = np.zeros(len(h))
    kb.bw_exact_path(p, kb.bw_sigma(p), np.array(h, float), np.array(du, float), he, kb.path_scratch(len(h)))
    return he


@njit
def _rk4_loop(P, A, B, G, D1, D2, h, du, m):
    d = du / m
    q = P @ d
    for _ in range(m):
        k1 = _rate(A, B, G, D1, D2, d, q, h)
        k2 = _rate(A, B, G, D1, D2, d, q, h + 0.5 * k1)
        k3 = _rate(A, B, G, D1, D2, d, q, h + 0.5 * k2)
        k4 = _rate(A, B, G, D1, D2, d, q, h + k3)
        h = h + (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
    return h


@njit
def _rate(A, B, G, D1, D2, d, q, x):
    return A @ d - B @ (np.abs(q) * x) - G @ (q * np.abs(x)) - D1 @ (q * x) - D2 @ (np.abs(q) * np.abs(x))


def _rk4(cfg, h, du, m):
    a = cfg.arrays()
    P, A, B, G, D1, D2 = (np.ascontiguousarray(a[k], dtype=float) for k in ("P", "A", "B", "Gamma", "Delta1", "Delta2"))
    return _rk4_loop(P, A, B, G, D1, D2, np.array(h, float), np.asarray(du, float), int(m))


@pytest.mark.parametrize("which", ["paper", "generalized"])
@pytest.mark.parametrize("h0,du", [((0.0, 0.0), (3000.0, -2000.0)), ((1.0, -1.0), (-2500.0, 6.0)),
                                   ((-1.0, 0.5), (8000.0, 400.0)), ((0.5, 0.5), (-1500.0, -5000.0))])
def test_a_long_path_ends_where_a_fine_integration_ends(base, which, h0, du):
    """Steps of 1.5–8 kV (κ 14–70, beyond the 32 Taylor pieces summed one by one; h changing sign on the way, one
    axis nearly still) end where 40 000 RK4 sub-steps end, to 1e-10 of the loop."""
    cfg = base.hysteresis if which == "paper" else _generalized(base.hysteresis)
    h = 3e-6 * np.array(h0)
    ref = _rk4(cfg, h, du, 40000)
    got = _exact(cfg, h, du)
    assert np.max(np.abs(got - ref)) < 1e-10 * max(3e-6, np.max(np.abs(ref)))


@pytest.mark.parametrize("which", ["paper", "generalized"])
@pytest.mark.parametrize("size", [1e6, 1e9, 1e13, 1e100])
def test_a_huge_monotone_step_saturates_h_at_the_orthant_fixed_point(base, which, size):
    """Bouc-Wen saturates: far along a straight step h is the fixed point ``−M⁻¹·A·dU`` of the orthant it ends in
    (``dh/dλ = A·dU + M·h = 0``), to rounding, whatever the step's size; the two-axis kernel gives the generic
    kernel's numbers bit for bit."""
    cfg = base.hysteresis if which == "paper" else _generalized(base.hysteresis)
    a = cfg.arrays()
    p = kb.params_of(a)
    c = kb.model_coeff_tuple(kb.coeffs_2x2(p))
    sigma = kb.bw_sigma(p)
    for h0, d in [((2e-6, -1e-6), (1.0, -0.3)), ((-4e-6, 3e-6), (1.0, 0.9)), ((0.0, 0.0), (-0.2, 1.0))]:
        du = size * np.array(d)
        he = _exact(cfg, h0, du)
        assert np.all(np.isfinite(he))
        assert np.array_equal(np.array(kb.bw2_exact_path(c, sigma, h0[0], h0[1], du[0], du[1])), he)
        q = a["P"] @ du
        s = np.where(he != 0, np.sign(he), 1.0)
        M = -(np.abs(q)[None, :] * (a["B"] + a["Delta2"] * s[None, :]) + q[None, :] * (a["Gamma"] * s[None, :]
                                                                                       + a["Delta1"]))
        fixed = -np.linalg.solve(M, a["A"] @ du)
        assert np.max(np.abs(he - fixed)) < 1e-12 * np.max(np.abs(fixed))


def make_core(base, **settings):
    book = ParameterBook(base)
    book.values.update(config_to_params(base))
    book.values["cascade.vibration"] = False
    settings.setdefault("reference_limit", ())
    return CompensatorCore(book, book.end_declarations(), CompensatorSettings(**settings))


def _huge_stream(n=600):
    """10 µm, then 1 m, ±1e6 m and 2e6 m steps, then back to 10 µm."""
    t = np.arange(n)
    x = np.select([t < 100, t < 200, t < 300, t < 400, t < 500], [10e-6, 1.0, 1e6, -1e6, 1e6], 10e-6)
    y = np.select([t < 100, t < 200, t < 300, t < 400, t < 500], [-5e-6, 0.0, -1e6, 1e6, 3e5], -5e-6)
    return np.stack([x, y], 1) + 1e-7 * np.sin(0.3 * t)[:, None]


def _run(core, ref, splits):
    out, k, i = [], 0, 0
    for size in list(splits) + [len(ref)]:
        if k >= len(ref):
            break
        b = ref[k:k + size]
        em = core.on_reference(S0 + k * DT, b, 0.001 * i)
        assert not em.log, em.log
        out.append(em.voltage[0].u)
        k += len(b)
        i += 1
    return np.vstack(out)


@pytest.mark.parametrize("splits", [(1, 2, 3, 250), (7, 50, 93, 111)])
def test_huge_references_through_the_core_are_finite_limited_and_block_size_invariant(base, splits):
    """With reference_limit empty, 1 m, ±1e6 m and 2e6 m steps give finite voltages within ±limits.voltage
    (saturated the way the reference asks) and bit-identical whatever the block split.  (Back at 10 µm the voltage
    stays saturated for a while: the creep inverse remembers the huge reference through its slow poles.)"""
    ref = _huge_stream()
    whole = _run(make_core(base), ref, [len(ref)])
    split = _run(make_core(base), ref, splits * 3)
    assert np.array_equal(whole, split)
    assert np.all(np.isfinite(whole)) and np.max(np.abs(whole)) <= base.limits.voltage
    assert np.all(whole[210:300, 0] == 200.0) and np.all(whole[310:400, 0] == -200.0)


@pytest.mark.parametrize("which", ["paper", "generalized"])
def test_without_voltage_limits_the_inverse_is_exact_on_huge_references(base, which):
    """No voltage limit: the compensator's voltages for 1 m … 1e6 m references (kV to TV) are the model's exact
    inverse — the model driven by them gives the reference back to 1e-12 of its size — and the two share h."""
    cfg = base.hysteresis if which == "paper" else _generalized(base.hysteresis)
    ref = np.ascontiguousarray(_huge_stream(500))
    comp = HysteresisCompensator(cfg)
    u = comp.process(ref)
    assert np.all(np.isfinite(u))
    y = BoucWenModel(cfg).process(u)
    assert np.all(np.abs(y - ref) <= 1e-12 * np.maximum(np.max(np.abs(ref), axis=1, keepdims=True), 1e-5))


@pytest.mark.parametrize("limit", [200.0, None])
def test_an_overflowing_reference_never_makes_a_non_finite_voltage(base, limit):
    """References so large that their exact voltage overflows (1e305 m, mixed signs): finite voltages (clamped to
    ±limit in the direction asked, or held without a limit), a state that stays finite, and ordinary output again
    once the reference is back."""
    comp = HysteresisCompensator(base.hysteresis, voltage_limit=limit)
    ref = np.array([[10e-6, 0.0]] * 3 + [[1e305, -1e305]] * 3 + [[-1e305, 1e305], [1.7e308, -1.7e308]]
                   + [[10e-6, 0.0]] * 3)
    u = comp.process(ref)
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(comp.h))
    if limit is not None:
        assert np.array_equal(u[3], [200.0, -200.0]) and np.array_equal(u[6], [-200.0, 200.0])
    fresh = HysteresisCompensator(base.hysteresis, voltage_limit=limit)
    assert np.all(np.abs(u[-1]) < 200.0) and np.isfinite(fresh.process(ref[-3:])).all()


def test_a_reference_beyond_the_hard_bound_is_refused_with_one_line_even_with_the_limit_empty(base):
    """reference_limit empty: 1e6 m is processed, but a reference beyond 1e12 × the stage's reach (where the
    linear stages' states would overflow) is refused whole with one ERROR line naming the bound, and changes no
    state."""
    reach = reachable_range(base, margin=1.0)[1]   # x
    bound = HARD_REFERENCE_FACTOR * reach
    assert 1e6 < bound < 1e300
    core, clean = make_core(base), make_core(base)
    before = _run(core, np.tile([10e-6, 0.0], (N, 1)), [N])
    _run(clean, np.tile([10e-6, 0.0], (N, 1)), [N])
    bad = np.tile([10e-6, 0.0], (N, 1))
    bad[5] = [1e300, 0.0]
    em = core.on_reference(S0 + N * DT, bad, 0.01)
    assert em.voltage == [] and len(em.log) == 1 and em.log[0][0] == ERROR
    assert "hard reference bound" in em.log[0][1] and "\n" not in em.log[0][1]
    assert core.rejected_blocks == 1
    em = core.set_point([-1e300, 0.0])
    assert em.hold_timer is None and "hard reference bound" in em.log[0][1]
    after = core.on_reference(S0 + N * DT, np.tile([10e-6, 0.0], (N, 1)), 0.02).voltage[0].u
    want = clean.on_reference(S0 + N * DT, np.tile([10e-6, 0.0], (N, 1)), 0.02).voltage[0].u
    assert np.array_equal(after, want) and before.shape == (N, 2)
    assert core.on_reference(S0 + 2 * N * DT, np.tile([0.99 * bound, 0.0], (2, 1)), 0.03).voltage
