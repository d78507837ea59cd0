"""The common shape of every streaming stage (pure).

A :class:`Stage` maps a block ``[N, n_in]`` to a block ``[N, n_out]``, carries its state between blocks (the output
is bit-identical whatever the block split), can be put back to rest (``reset``) and exposes that state as a plain
mapping of arrays (``state()`` returns copies, ``load_state`` copies them in), so that a new stage can start from
the state of the one it replaces (for linear stages in modal form:
:func:`~piezo_ff_ros.core.lti.transfer_linear_state`).
"""
from __future__ import annotations

from typing import Mapping, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Stage", "StageState", "Processor", "as_block"]


def as_block(x: ArrayLike, n: int | None = None, what: str = "") -> np.ndarray:
    """``x`` as a C-contiguous float64 block ``[N, n]`` — what every stage's ``process`` takes.

    Parameters
    ----------
    x : array_like
        The block.
    n : int or None
        Columns expected (None: any).
    what : str
        Its kind for the error (``"reference"``, ``"voltage"``; empty: none).

    Returns
    -------
    ndarray
        ``x`` itself when it already is one, else a converted copy.

    Raises
    ------
    ValueError
        ``expected a [what ]block of shape [N, n], got (…)``.
    """
    b = np.ascontiguousarray(x, dtype=float)
    if b.ndim != 2 or (n is not None and b.shape[1] != n):
        kind = f"{what} " if what else ""
        raise ValueError(f"expected a {kind}block of shape [N, {n if n is not None else 'axes'}], got {b.shape}")
    return b

#: a stage's state: named arrays (copies)
StageState = Mapping[str, np.ndarray]


class Processor(Protocol):
    """The least a streaming block processor offers (a plant, an effect): ``process(block) -> block``, ``reset()``."""

    def process(self, block: np.ndarray, /) -> np.ndarray:
        """Run one block; the state moves on by ``block.shape[0]`` samples."""

    def reset(self) -> None:
        """All states back to rest."""


@runtime_checkable
class Stage(Protocol):
    """A streaming stage: ``process(block[N, n_in]) -> block[N, n_out]`` with state carried between blocks."""

    @property
    def n_in(self) -> int:
        """Number of input columns."""

    @property
    def n_out(self) -> int:
        """Number of output columns."""

    def process(self, block: np.ndarray) -> np.ndarray:
        """Run one block; the state moves on by ``block.shape[0]`` samples."""

    def reset(self) -> None:
        """All states back to rest."""

    def state(self) -> StageState:
        """A copy of the carried state (named arrays)."""

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state` of a stage of the same shape) into this stage."""
