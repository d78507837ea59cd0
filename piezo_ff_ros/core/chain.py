"""Stages in series: one :class:`Chain` for the plant, the compensator cascade and anything built from stages (pure).

A chain is itself a stage: ``process(block) -> block`` runs its stages one after the other, ``reset()``,
``state()`` / ``load_state()`` delegate to them (``{stage name: stage state}``).  The signals between stages are
read through :meth:`Chain.process_with_taps`, which returns ``(output, {stage name: that stage's output})`` — the
return type of ``process`` never changes.

Fusion: runs of consecutive two-axis stages that offer :meth:`fused_part` (modal banks, the creep compensator,
the Bouc-Wen model and compensator — see :mod:`piezo_ff_ros.core.kernels.fused`) are run by one compiled pass per
block, nested chains included.  The fused pass computes every sample with the stages' own per-sample step
functions in the same order, on the stages' own state arrays: its output and the states it leaves are the numbers
the stages give one by one, whatever the block split (``test/test_chain.py``).
"""
from __future__ import annotations

from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from .kernels.fused import FusedPass, FusedPart, plan_fusion
from .stage import Processor, StageState, as_block

__all__ = ["Chain", "leaves", "FusedPass", "FusedPart"]


def leaves(stage: Any) -> Iterator[Any]:
    """Every non-chain stage inside ``stage`` (itself when it is not a chain), in processing order."""
    if isinstance(stage, Chain):
        for _, st in stage.entries:
            if st is not None:
                yield from leaves(st)
    else:
        yield stage


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
        """How :meth:`process` runs: stages and :class:`~.kernels.fused.FusedPass` objects, in order."""
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

