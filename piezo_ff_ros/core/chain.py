"""Stages in series: one :class:`Chain` for the plant, the compensator cascade and anything built from stages (pure).

A chain is itself a stage: ``process(block) -> block`` runs its stages one after the other, ``reset()``,
``state()`` / ``load_state()`` delegate to them (``{stage name: stage state}``).  The signals between stages are
read through :meth:`Chain.process_with_taps`, which returns ``(output, {stage name: that stage's output})`` — the
return type of ``process`` never changes.

Fusion: runs of consecutive two-axis stages that offer :meth:`fused_part` (modal banks, the creep compensator,
the Bouc-Wen model and compensator — see :mod:`piezo_ff_ros.core.kernels.fused`) are run by one compiled pass per
block (:class:`FusedPass`, planned by :func:`plan_fusion`), nested chains included.  The fused pass computes every
sample with the stages' own per-sample step functions in the same order, on the stages' own state arrays: its output
and the states it leaves are the numbers the stages give one by one, whatever the block split
(``test/test_chain.py``).
"""
from __future__ import annotations

from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from .kernels.bouc_wen import N_COUNTERS
from .kernels.fused import FusedPart, fused_kernel, fused_layout, slots_of
from .stage import Processor, StageState, as_block

__all__ = ["Chain", "leaves", "FusedPass", "FusedPart", "plan_fusion"]


def leaves(stage: Any) -> Iterator[Any]:
    """Every non-chain stage inside ``stage`` (itself when it is not a chain), in processing order."""
    if isinstance(stage, Chain):
        for _, st in stage.entries:
            if st is not None:
                yield from leaves(st)
    else:
        yield stage


class FusedPass:
    """Consecutive fusable stages run by one compiled kernel (:func:`~.kernels.fused.fused_kernel`; built by
    :func:`plan_fusion`)."""

    def __init__(self, stages: Sequence[Any], parts: Sequence[FusedPart]) -> None:
        slots = slots_of(parts)
        if slots is None or len(parts) < 1:
            raise ValueError("fused pass: the stages do not fit the slot order VIB, CINV, COMP, MODEL, CREEP, DYN")
        self.stages = list(stages)
        self.n_in = 2
        self.n_out = 2
        layout = fused_layout(parts, slots)
        self.P, self.L = layout.P, layout.L
        self._x, self._comp, self._model, self._count = layout.x, layout.comp, layout.model, layout.counter
        self.slots = slots
        self._counters = np.zeros(N_COUNTERS, np.int64)
        self._kernel = fused_kernel(slots, parts)

    def reset(self) -> None:
        """All states back to rest."""
        for st in self.stages:
            st.reset()

    def process(self, block: np.ndarray) -> np.ndarray:
        """Run one block ``[N, 2] → [N, 2]`` through every stage of the pass; the states move on by N samples."""
        u = as_block(block, 2)
        y = np.empty_like(u)
        counters = self._counters
        x = self._x
        ch, cu, cs, cg = self._comp
        mh, mu, ms = self._model
        self._kernel(self.P, self.L, x[0], x[1], x[2], x[3], ch, cu, cs, cg, mh, mu, ms, counters, u, y)
        if self._count is not None:
            self._count(counters)
        return y


def plan_fusion(stages: Sequence[Any]) -> list[Any]:
    """``stages`` with every run of two or more consecutive fusable stages replaced by one :class:`FusedPass`.

    Parameters
    ----------
    stages : sequence
        Stages in processing order (not chains).

    Returns
    -------
    list
        Stages and fused passes, in processing order.
    """
    out: list[Any] = []
    run: list[Any] = []
    parts: list[FusedPart] = []

    def flush() -> None:
        if len(run) >= 2:
            out.append(FusedPass(run, parts))
        else:
            out.extend(run)
        run.clear()
        parts.clear()
    for st in stages:
        fp = getattr(st, "fused_part", None)
        part = fp() if fp is not None else None
        if part is None:
            flush()
            out.append(st)
            continue
        if slots_of([*parts, part]) is None:
            flush()
        run.append(st)
        parts.append(part)
    flush()
    return out


class Chain:
    """Named stages in series; ``None`` entries are the identity (a switched-off stage keeps its tap name).

    Parameters
    ----------
    entries : sequence of (name, stage or None)
        The stages in processing order; each needs ``process`` and ``reset`` (the :class:`~.stage.Processor`
        protocol), and ``state``/``load_state`` for :meth:`state`/:meth:`load_state`.
    n_in, n_out : int, optional
        Column counts when no stage tells them (default: the first stage's ``n_in``, the last stage's ``n_out``).
    fuse : bool
        Run runs of fusable stages as one compiled pass (:meth:`process` only; default True).
    """

    def __init__(self, entries: Sequence[tuple[str, Processor | None]], n_in: int | None = None,
                 n_out: int | None = None, fuse: bool = True) -> None:
        names = [name for name, _ in entries]
        if len(set(names)) != len(names):
            raise ValueError(f"chain: stage names must be unique, got {names}")
        self.entries: list[tuple[str, Any]] = list(entries)
        present = [st for _, st in self.entries if st is not None]
        self._n_in = n_in if n_in is not None else (int(present[0].n_in) if present and hasattr(present[0], "n_in")
                                                    else None)
        self._n_out = n_out if n_out is not None else (int(present[-1].n_out)
                                                       if present and hasattr(present[-1], "n_out") else self._n_in)
        self.fuse = fuse
        self._plan: list[Any] | None = None

    # -- shape -------------------------------------------------------------------------------------------------
    @property
    def n_in(self) -> int:
        """Number of input columns."""
        if self._n_in is None:
            raise ValueError("chain: the number of input columns is unknown (give n_in)")
        return self._n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        if self._n_out is None:
            raise ValueError("chain: the number of output columns is unknown (give n_out)")
        return self._n_out

    @property
    def names(self) -> list[str]:
        """The stage names, in processing order."""
        return [name for name, _ in self.entries]

    def __getitem__(self, name: str) -> Any:
        for n, st in self.entries:
            if n == name:
                return st
        raise KeyError(name)

    def head(self, n: int) -> "Chain":
        """A chain of the first ``n`` entries (the same stage objects, so the same states)."""
        return Chain(self.entries[:n], n_in=self._n_in, n_out=None, fuse=self.fuse)

    # -- running -----------------------------------------------------------------------------------------------
    def _check(self, block: np.ndarray) -> np.ndarray:
        x = as_block(block, self._n_in)
        return x

    def plan(self) -> list[Any]:
        """How :meth:`process` runs: stages and :class:`FusedPass` objects, in order."""
        if self._plan is None:
            flat = list(leaves(self))
            self._plan = plan_fusion(flat) if self.fuse else flat
        return self._plan

    def process(self, block: np.ndarray) -> np.ndarray:
        """Run one block through every stage (fused where possible); the state moves on by N samples.

        Parameters
        ----------
        block : ndarray
            ``[N, n_in]``.

        Returns
        -------
        ndarray
            ``[N, n_out]``.
        """
        x = self._check(block)
        for st in self.plan():
            x = st.process(x)
        return x

    def process_with_taps(self, block: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`process`, also returning every stage's output by stage name (stage by stage, not fused).

        Parameters
        ----------
        block : ndarray
            ``[N, n_in]``.

        Returns
        -------
        out : ndarray
            ``[N, n_out]``, the same numbers as :meth:`process`.
        taps : dict
            ``{name: output of that entry}`` for every entry (a ``None`` entry repeats its input).
        """
        x = self._check(block)
        taps: dict[str, np.ndarray] = {}
        for name, st in self.entries:
            if st is not None:
                x = st.process(x)
            taps[name] = x
        return x, taps

    def reset(self) -> None:
        """All states back to rest."""
        for _, st in self.entries:
            if st is not None:
                st.reset()

    def state(self) -> dict[str, StageState]:
        """``{name: stage.state()}`` for every present stage (copies)."""
        out: dict[str, StageState] = {}
        for name, st in self.entries:
            if st is None:
                continue
            if not hasattr(st, "state"):
                raise TypeError(f"chain: stage {name!r} ({type(st).__name__}) has no state()")
            out[name] = st.state()
        return out

    def load_state(self, state: Mapping[str, StageState]) -> None:
        """Load :meth:`state`'s result (``{name: stage state}``; names left out keep their state)."""
        for name, st_state in state.items():
            st = self[name]
            if st is None:
                raise KeyError(f"chain: stage {name!r} is switched off")
            st.load_state(st_state)

