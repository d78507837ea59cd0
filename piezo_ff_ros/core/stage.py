"""The common shape of every streaming stage, and the state transfer that makes a stage swap bumpless (pure).

A :class:`Stage` maps a block ``[N, n_in]`` to a block ``[N, n_out]``, carries its state between blocks (the output
is bit-identical whatever the block split), can be put back to rest (``reset``) and exposes that state as a plain
mapping of arrays (``state()`` returns copies, ``load_state`` copies them in), so that a new stage can start from
the state of the one it replaces.

:func:`transfer_linear_state` is that transfer for linear stages in block-diagonal modal form
(:class:`~piezo_ff_ros.core.lti.DiscreteModalSS`), in two steps:

1. **Same input history** — a modal block's state is determined by its ``(A_blk, B_blk)`` and the input history
   alone (the residues live in C).  Every new block whose ``(A_blk, B_blk)`` equals an old block's takes that
   block's state: it is then exactly the state the new stage would have, had it been fed the same input since the
   start — a gain change (``creep.Cr.xx.k``) or an equivalent factorisation of a denominator keeps every mode.
2. **Same future output** — the new blocks left (modes that did not exist before) get the state that best
   reproduces the old stage's free response ``C·A^k·(x − x_ss)`` over an infinite horizon (deviations from each
   realisation's steady state for the last input, when it is given), minus what the matched blocks already give:
   a least-squares problem weighted by the discrete observability Gramians (Stein equations, solved in the
   complex modal basis).  For a different realisation of the same model (a similarity transform of C(s)), this
   recovers the exact transformed state; for a held input, the new model's steady state.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from .lti import DiscreteModalSS

__all__ = ["Stage", "StageState", "Processor", "as_block", "transfer_linear_state", "free_response_match"]


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


def _blocks(ss: DiscreteModalSS) -> list[tuple[int, int]]:
    """(offset, size) of every diagonal block of a DiscreteModalSS."""
    out, off = [], 0
    for s in ss.sizes:
        out.append((off, int(s)))
        off += int(s)
    return out


def _same_block(ss_a: DiscreteModalSS, oa: int, ss_b: DiscreteModalSS, ob: int, s: int, rtol: float) -> bool:
    Aa = ss_a.A[oa:oa + s, oa:oa + s]
    Ab = ss_b.A[ob:ob + s, ob:ob + s]
    Ba = ss_a.B[oa:oa + s]
    Bb = ss_b.B[ob:ob + s]
    scale_a = max(np.max(np.abs(Aa)), 1e-300)
    scale_b = max(np.max(np.abs(Ba)), 1e-300)
    return bool(np.max(np.abs(Aa - Ab)) <= rtol * scale_a and Ba.shape == Bb.shape
                and np.max(np.abs(Ba - Bb), initial=0.0) <= rtol * scale_b)


def _stein_cross(A2: np.ndarray, A1: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``X = Σ_k (A2ᵀ)^k Q A1^k`` (the solution of ``X − A2ᵀ X A1 = Q``), for stable, diagonalisable A1, A2."""
    if A2.shape[0] == 0 or A1.shape[0] == 0:
        return np.zeros((A2.shape[0], A1.shape[0]))
    l2, V2 = np.linalg.eig(A2.T)
    l1, V1 = np.linalg.eig(A1)
    Qm = np.linalg.solve(V2, Q.astype(complex)) @ V1
    Y = Qm / (1.0 - l2[:, None] * l1[None, :])
    return np.real(V2 @ Y @ np.linalg.inv(V1))


def free_response_match(A_new: np.ndarray, C_new: np.ndarray, A_old: np.ndarray, C_old: np.ndarray,
                        x_old: np.ndarray) -> np.ndarray:
    """The state of ``(A_new, C_new)`` whose free response ``C_new A_new^k x`` best matches ``C_old A_old^k x_old``
    (least squares over k = 0…∞, minimum-norm where modes are unobservable).

    Parameters
    ----------
    A_new, C_new : ndarray
        The new realisation's state and output matrices (discrete, stable).
    A_old, C_old : ndarray
        The old realisation's state and output matrices.
    x_old : ndarray
        The old state.

    Returns
    -------
    ndarray
        The new state (minimum norm where the new modes are unobservable).
    """
    n = A_new.shape[0]
    if n == 0:
        return np.zeros(0)
    W = _stein_cross(A_new, A_new, C_new.T @ C_new)
    X = _stein_cross(A_new, A_old, C_new.T @ C_old) if A_old.shape[0] else np.zeros((n, 0))
    rhs = X @ x_old if A_old.shape[0] else np.zeros(n)
    W = 0.5 * (W + W.T)
    sol: np.ndarray = np.linalg.lstsq(W, rhs, rcond=1e-12)[0]
    return sol


def _steady_state(ss: DiscreteModalSS, u: np.ndarray | None) -> np.ndarray:
    n = ss.n_states
    if n == 0 or u is None:
        return np.zeros(n)
    return np.linalg.solve(np.eye(n) - ss.A, ss.B @ np.asarray(u, float))


def transfer_linear_state(ss_old: DiscreteModalSS, x_old: np.ndarray, ss_new: DiscreteModalSS, u_last: np.ndarray | None = None,
                          rtol: float = 1e-9) -> tuple[np.ndarray, int]:
    """State for ``ss_new`` continuing ``ss_old`` in state ``x_old`` (see the module docstring).

    ``u_last`` (the stage's last input), when given, makes the fit of the new modes work on deviations from each
    realisation's own steady state for that input: a held input then gives the new stage's steady state (its
    output moves only by the change of DC gain), and a model-equal realisation still gets the transformed state.

    Parameters
    ----------
    ss_old, ss_new : DiscreteModalSS
        The replaced and the replacing stage's discrete modal realisations.
    x_old : ndarray
        The replaced stage's state.
    u_last : ndarray, optional
        The stage's last input (see above).
    rtol : float
        Relative tolerance for two modal blocks to count as equal.

    Returns
    -------
    x_new : ndarray
        The new state.
    matched : int
        How many of the new blocks inherited an old block's state exactly (the others were fitted).
    """
    x_new = np.zeros(ss_new.n_states)
    old_blocks = _blocks(ss_old)
    used = [False] * len(old_blocks)
    unmatched: list[tuple[int, int]] = []
    matched_states = np.zeros(ss_old.n_states, bool)
    n_matched = 0
    for ob, s in _blocks(ss_new):
        for i, (oa, sa) in enumerate(old_blocks):
            if not used[i] and sa == s and _same_block(ss_old, oa, ss_new, ob, s, rtol):
                used[i] = True
                x_new[ob:ob + s] = x_old[oa:oa + s]
                matched_states[oa:oa + s] = True
                n_matched += 1
                break
        else:
            unmatched.append((ob, s))
    if unmatched and ss_old.n_states:
        idx = np.concatenate([np.arange(ob, ob + s) for ob, s in unmatched])
        keep = np.flatnonzero(~np.isin(np.arange(ss_new.n_states), idx))
        # target: the old free response minus what the matched new blocks already produce
        xs_old, xs_new = _steady_state(ss_old, u_last), _steady_state(ss_new, u_last)
        A_old = np.block([[ss_old.A, np.zeros((ss_old.n_states, len(keep)))],
                          [np.zeros((len(keep), ss_old.n_states)), ss_new.A[np.ix_(keep, keep)]]])
        C_old = np.hstack([ss_old.C, -ss_new.C[:, keep]])
        x_target = np.concatenate([x_old - xs_old, x_new[keep] - xs_new[keep]])
        x_new[idx] = xs_new[idx] + free_response_match(ss_new.A[np.ix_(idx, idx)], ss_new.C[:, idx], A_old, C_old,
                                                       x_target)
    return x_new, n_matched
