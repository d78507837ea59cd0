"""Fused chains: consecutive two-axis stages run as one compiled pass per block (pure).

The standard chain ``Y_R → C(s) → creep⁻¹ → hysteresis⁻¹ → U → Bouc-Wen → K + Cr(s) → G_L(s) → Y`` is six stages
in six slots::

    VIB (modal bank) → CINV (creep compensator) → COMP (hysteresis compensator)
        → MODEL (Bouc-Wen model) → CREEP (modal bank, D = K) → DYN (modal bank)

Any run of consecutive stages that fills some of these slots in this order (a compensator cascade, a plant, both,
or part of either) is run by one compiled kernel (``fused_run``, source from :func:`fused_source`): one loop over the
samples, each sample through every present slot with the stages' own loop kernels (the banks' loops specialised to
their structure by :mod:`.specialise`, or the generic :func:`~.modal.bank2_loop`, :func:`~.modal.inverse2_loop`;
:func:`~.bouc_wen.bw_comp_run_2x2`, :func:`~.bouc_wen.bw_model_run_2x2`), on the stages' own state arrays.  It
therefore gives the numbers of the stages run one by one — and, like them, the same numbers whatever the block split
— and one call replaces six.  The block is run chunk by chunk (:data:`_CHUNK` samples in a cache-resident buffer),
each slot running its own loop kernel over the chunk: the processor overlaps successive samples of a stage as in the
stage's own kernel (a per-sample loop through all six slots, tried, is slower: each sample waits for the whole
chain).

A stage joins a fused pass by offering ``fused_part() -> FusedPart | None`` (its slot kind, constants and state
arrays); :func:`fused_layout` packs the parts for the kernel.  Which stages run fused is decided beside the chain
(:func:`piezo_ff_ros.core.chain.plan_fusion`, :class:`piezo_ff_ros.core.chain.FusedPass`).
"""
from __future__ import annotations

from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from .._jit import njit
from .modal import gather_2x2, scatter_2x2
from .specialise import bank_loop_module, enabled, inverse_loop_module, load_generated

__all__ = ["BANK", "INVERSE", "COMP", "MODEL", "SLOT_KINDS", "FusedPart", "FusedLayout", "slots_of", "fused_layout",
           "fused_source", "fused_kernel"]

#: kinds of fusable stage
BANK, INVERSE, COMP, MODEL = 0, 1, 2, 3
#: the kind of each slot, in processing order (VIB, CINV, COMP, MODEL, CREEP, DYN)
SLOT_KINDS = (BANK, INVERSE, COMP, MODEL, BANK, BANK)
_BANK_SLOTS = (0, 1, 4, 5)
_L_BANK = 6          # L[6 + 8·b …]: bank b's layout
_L_COMP = 6 + 8 * 4  # L[38], L[39]: compensator coefficients offset in P, exact flag
_L_MODEL = _L_COMP + 2
#: samples per chunk of the fused loop (its buffer stays in L1)
_CHUNK = 256


class FusedPart(NamedTuple):
    """What a stage gives a fused pass.

    ``kind`` :data:`BANK`: ``consts = (W, feeds, D, offsets, sizes)`` (:func:`~.modal.pad_to_2x2`), ``state = (x,)``;
    :data:`INVERSE`: the same with ``K⁻¹`` for D; :data:`COMP`: ``consts = (coeffs[36], exact, ulim, dulim)``,
    ``state = (h, u_prev, started, signs)``; :data:`MODEL`: ``consts = (coeffs[28],)``,
    ``state = (h, u_prev, started)``.  ``counter`` receives the compensator's counters after each block.
    """

    kind: int
    consts: tuple[Any, ...]
    state: tuple[np.ndarray, ...]
    counter: Callable[[np.ndarray], None] | None = None


def slots_of(parts: Sequence[FusedPart]) -> list[int] | None:
    """The slot of each part (increasing), or None when the parts do not fit the slot order.

    Parameters
    ----------
    parts : sequence of FusedPart
        The stages' parts, in processing order.

    Returns
    -------
    list of int or None
        The slot (0 VIB … 5 DYN) of each part.
    """
    slots, s = [], 0
    for p in parts:
        while s < len(SLOT_KINDS) and SLOT_KINDS[s] != p.kind:
            s += 1
        if s == len(SLOT_KINDS):
            return None
        slots.append(s)
        s += 1
    return slots


class FusedLayout(NamedTuple):
    """The arguments of the fused kernel for a set of parts (built by :func:`fused_layout`).

    ``P`` holds every constant (float64) and ``L`` their layout (offsets, sizes, flags; int64); ``x`` the four bank
    slots' state arrays (VIB, CINV, CREEP, DYN; empty when absent); ``comp`` the compensator's
    ``(h, u_prev, started, signs)``, ``model`` the Bouc-Wen model's ``(h, u_prev, started)`` (dummies when absent);
    ``counter`` the compensator's counter callback (None without one).  The state arrays are the stages' own: the
    kernel moves them in place.
    """

    P: np.ndarray
    L: np.ndarray
    x: list[np.ndarray]
    comp: tuple[np.ndarray, ...]
    model: tuple[np.ndarray, ...]
    counter: Callable[[np.ndarray], None] | None


def fused_layout(parts: Sequence[FusedPart], slots: Sequence[int]) -> FusedLayout:
    """Pack the parts' constants and state arrays the way the fused kernel reads them.

    Parameters
    ----------
    parts : sequence of FusedPart
        The stages' parts, in processing order.
    slots : sequence of int
        Their slots (:func:`slots_of`).

    Returns
    -------
    FusedLayout
    """
    P: list[np.ndarray] = []
    L = np.zeros(_L_MODEL + 1, np.int64)
    extra: list[np.ndarray] = []
    dummy_x = np.zeros(0)
    x = [dummy_x, dummy_x, dummy_x, dummy_x]
    comp: tuple[np.ndarray, ...] = (np.zeros(2), np.zeros(2), np.zeros(1, np.bool_), np.ones(2))
    model: tuple[np.ndarray, ...] = (np.zeros(2), np.zeros(2), np.zeros(1, np.bool_))
    count: Callable[[np.ndarray], None] | None = None
    n_p = 0

    def put(a: np.ndarray) -> int:
        nonlocal n_p
        off = n_p
        P.append(np.ascontiguousarray(a, float).reshape(-1))
        n_p += P[-1].size
        return off
    n_l = len(L)

    def put_i(a: np.ndarray) -> int:
        nonlocal n_l
        off = n_l
        extra.append(np.ascontiguousarray(a, np.int64).reshape(-1))
        n_l += extra[-1].size
        return off
    for part, slot in zip(parts, slots):
        L[slot] = 1
        if slot in _BANK_SLOTS:
            b = _BANK_SLOTS.index(slot)
            W, feeds, D, offsets, sizes = part.consts
            base = _L_BANK + 8 * b
            L[base:base + 6] = (put(W), put(D), len(sizes), put_i(offsets), put_i(sizes), put_i(feeds))
            x[b] = part.state[0]
        elif slot == 2:
            coeffs, exact, ulim, dulim = part.consts
            L[_L_COMP] = put(np.concatenate([coeffs, [ulim, dulim]]))
            L[_L_COMP + 1] = int(bool(exact))
            comp = part.state  # (h, u_prev, started, signs)
            count = part.counter
        else:
            L[_L_MODEL] = put(part.consts[0])
            model = part.state  # (h, u_prev, started)
    if not L[2]:  # absent: zeros, so that the kernel's reads stay inside P
        L[_L_COMP] = put(np.zeros(38))
    if not L[3]:
        L[_L_MODEL] = put(np.zeros(28))
    return FusedLayout(np.ascontiguousarray(np.concatenate(P)), np.ascontiguousarray(np.concatenate([L, *extra])),
                       x, comp, model, count)


@njit(inline="always")
def _bank(P: np.ndarray, L: np.ndarray, b: int,
          x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Bank ``b``'s coefficient table (a local copy), feeds, D (K⁻¹ for CINV) and its state in the two-axis
    layout."""
    base = 6 + 8 * b
    pW = L[base]
    pD = L[base + 1]
    nb = L[base + 2]
    W = P[pW:pW + 12 * nb].reshape((12, nb)).copy()
    D = P[pD:pD + 4].reshape((2, 2))
    feeds = L[L[base + 5]:L[base + 5] + nb].copy()
    xp = gather_2x2(L[L[base + 3]:L[base + 3] + nb], L[L[base + 4]:L[base + 4] + nb], x)
    return W, feeds, D, xp


@njit(inline="always")
def _unbank(L: np.ndarray, b: int, xp: np.ndarray, x: np.ndarray) -> None:  # pragma: no cover - compiled
    """Bank ``b``'s padded state back into its public layout."""
    base = 6 + 8 * b
    nb = L[base + 2]
    scatter_2x2(L[L[base + 3]:L[base + 3] + nb], L[L[base + 4]:L[base + 4] + nb], xp, x)


_FUSED_HEAD = """
import numpy as np

from piezo_ff_ros.core.kernels.bouc_wen import FALLBACKS, SATURATED, CompOptions, CompState
from piezo_ff_ros.core.kernels.bouc_wen import bw_comp_run_2x2, bw_model_run_2x2
from piezo_ff_ros.core.kernels.fused import _CHUNK, _bank, _unbank
from piezo_ff_ros.core.kernels.modal import bank2_loop, inverse2_loop
"""

# The fused kernel, written out for the present slots by :func:`fused_source`.  Each slot calls its stage's own loop:
# a bank slot with a loop specialised to its structure (:mod:`.specialise`) reads its coefficients in place and its
# state in the public layout; a generic bank slot gets a local copy of its table and its padded state (``_bank`` /
# ``_unbank``) for :func:`~.modal.bank2_loop` / :func:`~.modal.inverse2_loop`.
_FUSED_SETUP = """
@njit
def fused_run(P, L, x0, x1, x4, x5, ch, cu, cs, cg, mh, mu, ms, counters, u, y):  # pragma: no cover - compiled
    N = u.shape[0]
    pc = L[38]
    cco = P[pc:pc + 36]
    exact = L[39] != 0
    ulim = P[pc + 36]
    dulim = P[pc + 37]
    mco = P[L[40]:L[40] + 28]
    counters[FALLBACKS] = 0
    counters[SATURATED] = 0
    buf = np.empty((_CHUNK, 2))
    hs = np.empty((_CHUNK, 2))
    cst = CompState(ch, cu, cs, cg)
    copt = CompOptions(exact, ulim, dulim)
"""
_FUSED_CHUNK = """    for c0 in range(0, N, _CHUNK):
        n = min(_CHUNK, N - c0)
        b = buf[:n]
        for i in range(n):
            b[i, 0] = u[c0 + i, 0]
            b[i, 1] = u[c0 + i, 1]
"""
_FUSED_OUT = """        for i in range(n):
            y[c0 + i, 0] = b[i, 0]
            y[c0 + i, 1] = b[i, 1]
"""
_BANK_INDEX = {0: 0, 1: 1, 4: 2, 5: 3}  # slot → bank number in the layout L


def fused_source(slots: Sequence[int], loops: dict[int, tuple[str, str]]) -> str:
    """Source of the fused kernel for the present ``slots``.

    Parameters
    ----------
    slots : sequence of int
        The slots present (0 VIB … 5 DYN).
    loops : dict
        For bank slots (0, 1, 4, 5) with a specialised loop: ``slot → (function name, source line that imports it)``
        (from :func:`~.specialise.bank_loop_module`, :func:`~.specialise.inverse_loop_module`: the loop the stage
        runs alone, compiled once); the other bank slots call the generic loop (:func:`~.modal.bank2_loop`,
        :func:`~.modal.inverse2_loop`).

    Returns
    -------
    str
        Module source defining ``fused_run(P, L, x0, x1, x4, x5, ch, cu, cs, cg, mh, mu, ms, counters, u, y)``:
        the present slots of VIB → CINV → COMP → MODEL → CREEP → DYN over a block ``u [N, 2]`` → ``y [N, 2]``
        (``P``/``L``: the constants and their layout, :class:`FusedLayout`; ``x0, x1, x4, x5``: the banks' states in
        their public layout; ``ch, cu, cs, cg``: the compensator's h, last voltage, started, signs; ``mh, mu, ms``:
        the model's h, last voltage, started; ``counters`` ← this block's counts).  Chunk by chunk (``_CHUNK``
        samples in a cache-resident buffer) each slot runs its own loop kernel over the chunk: the processor
        overlaps successive samples of one stage as in the stage's own kernel.
    """
    head = [_FUSED_HEAD] + [src for _slot, (_name, src) in sorted(loops.items())]
    setup, calls, finish = [_FUSED_SETUP], [], []
    for slot in sorted(slots):
        if slot in _BANK_INDEX:
            k = _BANK_INDEX[slot]
            x = f"x{slot}"
            base = 6 + 8 * k
            if slot in loops:
                name = loops[slot][0]
                setup.append(f"    nb{slot} = L[{base + 2}]\n"
                             f"    W{slot} = P[L[{base}]:L[{base}] + 12 * nb{slot}].reshape((12, nb{slot}))\n"
                             f"    D{slot} = P[L[{base + 1}]:L[{base + 1}] + 4].reshape((2, 2))\n")
                args = f"D{slot}, W{slot}" if slot == 1 else f"W{slot}, D{slot}"
                calls.append(f"        {name}({args}, {x}, b, b, n)\n")
            else:
                setup.append(f"    W{slot}, f{slot}, D{slot}, xp{slot} = _bank(P, L, {k}, {x})\n")
                if slot == 1:
                    calls.append(f"        inverse2_loop(D{slot}, W{slot}, f{slot}, xp{slot}, b, b, n)\n")
                else:
                    calls.append(f"        bank2_loop(W{slot}, f{slot}, D{slot}, xp{slot}, b, b, n)\n")
                finish.append(f"    _unbank(L, {k}, xp{slot}, {x})\n")
        elif slot == 2:
            calls.append("        bw_comp_run_2x2(cco, cst, copt, b, b, counters)\n")
        elif slot == 3:
            calls.append("        bw_model_run_2x2(mco, mh, mu, ms, b, b, hs[:n])\n")
    body = "".join(setup) + _FUSED_CHUNK + "".join(calls) + _FUSED_OUT + "".join(finish)
    return "\n".join(head) + "\n" + body


def fused_kernel(slots: Sequence[int], parts: Sequence[FusedPart]) -> Callable[..., None]:
    """The compiled fused kernel for these slots and parts (bank loops specialised when :func:`~.specialise.enabled`).

    Parameters
    ----------
    slots : sequence of int
        The slot of each part (from the slot order VIB, CINV, COMP, MODEL, CREEP, DYN).
    parts : sequence of FusedPart
        The stages' parts, in order.

    Returns
    -------
    callable
        ``fused_run`` of :func:`fused_source` (imported from the kernel cache: numba caches it on disk).
    """
    loops: dict[int, tuple[str, str]] = {}
    if enabled():
        for part, slot in zip(parts, slots):
            if part.kind == BANK:
                W, _feeds, D, _offsets, sizes = part.consts
                mod = bank_loop_module(W, sizes, D)
                loops[slot] = (f"loop{slot}", f"from {mod.__name__} import bank_loop as loop{slot}\n")
            elif part.kind == INVERSE:
                W, _feeds, Kinv, _offsets, sizes = part.consts
                mod = inverse_loop_module(Kinv, W, sizes)
                loops[slot] = (f"loop{slot}", f"from {mod.__name__} import inverse_loop as loop{slot}\n")
    mod = load_generated(fused_source(slots, loops), "fused")
    fn: Callable[..., None] = mod.fused_run
    return fn
