"""Linear time-invariant building blocks: exact ZOH streaming filters of factored transfer functions, and the
state transfer that makes a swap of linear stages bumpless.

Why not ``scipy.signal.cont2discrete`` + ``tf2sos``: the paper's transfer functions are order 9 with coefficients
spanning 1e-7 … 1e9; expanded polynomials lose most of their digits.  Instead every transfer function is kept in
factored form (:mod:`piezo_ff_ros.core.transfer`: :class:`FactoredTF`, :class:`TFMatrix`, re-exported here), split
into its modes (partial fractions at distinct poles), and each mode is discretised exactly by zero-order hold
(``a = exp(pT)``, ``b = expm1(pT)/p``).  The result is a block-diagonal real state space (1×1 and 2×2 blocks) run by
one compiled loop with carried state: bit-identical whatever the block split.

Continuous MIMO state spaces (the H∞ controller) go through the same modal route when their eigenvectors are
well conditioned, otherwise through a dense ZOH (``scipy.linalg.expm``) in a single block.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from .kernels.fused import BANK, FusedPart
from .kernels.modal import bank_run, bank_run_2x2, pad_to_2x2
from .kernels.specialise import specialised_bank_run
from .stage import StageState, as_block
from .transfer import Block, FactoredTF, TFMatrix, continuous_modal_realisation, real_modal_blocks

__all__ = [
    "FactoredTF",
    "TFMatrix",
    "DiscreteModalSS",
    "LTIFilter",
    "FilterStage",
    "static_gain",
    "transfer_linear_state",
    "free_response_match",
    "continuous_modal_realisation",
]


def static_gain(x: ArrayLike, M: ArrayLike) -> np.ndarray:
    """``x @ M.T`` for a block ``x [N, n_in]`` and a gain ``M [n_out, n_in]``, each output summed input by input,
    so that every row gets the same numbers whatever N.

    ``x @ M.T`` itself does not: BLAS takes another path for a single row than for many, and the two round
    differently (~1e-21 m on a 1e-5 m signal) — a stream cut into one-sample blocks would not give the numbers of
    one whole block.

    Parameters
    ----------
    x : array_like
        ``[N, n_in]``.
    M : array_like
        ``[n_out, n_in]``.

    Returns
    -------
    ndarray
        ``[N, n_out]``: ``y[k, i] = (…(M[i, 0]·x[k, 0] + M[i, 1]·x[k, 1]) + …)``.
    """
    xa = np.asarray(x, float)
    Ma = np.asarray(M, float)
    if xa.ndim != 2 or Ma.ndim != 2 or xa.shape[1] != Ma.shape[1]:
        raise ValueError(f"static_gain: a block [N, {Ma.shape[-1]}] and a gain [n_out, n_in] expected, got "
                         f"{xa.shape} and {Ma.shape}")
    if Ma.shape[1] == 0:
        return np.zeros((xa.shape[0], Ma.shape[0]))
    y: np.ndarray = xa[:, 0:1] * Ma[:, 0]
    for j in range(1, Ma.shape[1]):
        y += xa[:, j:j + 1] * Ma[:, j]
    return y


#: the discretisations :meth:`DiscreteModalSS.zoh_from_tf_matrix` remembers (oldest dropped first)
_ZOH_CACHE: dict[Any, "DiscreteModalSS"] = {}
_ZOH_CACHE_SIZE = 32


# ----------------------------------------------------------------------------------------------------------------
# Discrete block-diagonal state space and its streaming filter
# ----------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DiscreteModalSS:
    """x[k+1] = A x[k] + B u[k];  y[k] = C x[k] + D u[k], with A block-diagonal (``sizes`` of its blocks)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    sizes: np.ndarray
    dt: float

    @property
    def n_states(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])

    @property
    def n_in(self) -> int:
        """Number of inputs."""
        return int(self.B.shape[1])

    @property
    def n_out(self) -> int:
        """Number of outputs."""
        return int(self.C.shape[0])

    @property
    def strictly_proper(self) -> bool:
        """True when D is zero (the output at k depends on inputs up to k − 1 only)."""
        return not np.any(self.D)

    # -- construction -----------------------------------------------------------------------------------------
    @staticmethod
    def zoh_from_tf_matrix(tfm: TFMatrix, dt: float) -> "DiscreteModalSS":
        """Each SISO entry discretised on its own by exact zero-order hold, stacked.

        Remembered per ``(tfm, dt)`` (a diagnosis rebuilds the same nominal plant hundreds of times; the poles and
        residues of order-9 entries dominate that): each call gets its own copy of the arrays.
        """
        try:
            key: Any = (tfm, float(dt))
            hit = _ZOH_CACHE.get(key)
        except TypeError:  # unhashable entries: no memory
            key, hit = None, None
        if hit is None:
            hit = DiscreteModalSS._zoh_from_tf_matrix(tfm, dt)
            if key is not None:
                if len(_ZOH_CACHE) >= _ZOH_CACHE_SIZE:
                    _ZOH_CACHE.pop(next(iter(_ZOH_CACHE)))
                _ZOH_CACHE[key] = hit
        return DiscreteModalSS(hit.A.copy(), hit.B.copy(), hit.C.copy(), hit.D.copy(), hit.sizes.copy(), hit.dt)

    @staticmethod
    def _zoh_from_tf_matrix(tfm: TFMatrix, dt: float) -> "DiscreteModalSS":
        n_out, n_in = tfm.shape
        blocks: list[Block] = []
        D = np.zeros((n_out, n_in))
        for i in range(n_out):
            for j in range(n_in):
                tf = tfm[i, j]
                if tf.is_zero():
                    continue
                p, c, d = tf.modes()
                D[i, j] += d
                a, beta = _zoh_scalar(p, dt)
                brow = np.zeros((len(p), n_in), complex)
                brow[:, j] = beta
                ccol = np.zeros((len(p), n_out), complex)
                ccol[:, i] = c
                blocks += real_modal_blocks(a, brow, ccol, pair_on=p)
        return DiscreteModalSS._assemble(blocks, D, n_in, n_out, dt)

    @staticmethod
    def zoh_from_ss(A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike, dt: float,
                    cond_limit: float = 1e8) -> "DiscreteModalSS":
        """Exact ZOH of a continuous MIMO state space; modal when the eigenvectors are well conditioned.

        Parameters
        ----------
        A, B, C, D : array_like
            The continuous state space.
        dt : float
            Sample time [s].
        cond_limit : float
            Largest condition number of the eigenvector matrix for the modal route (else a dense ``expm``).

        Returns
        -------
        DiscreteModalSS
        """
        Ad, Bd, Cd, Dd = (np.atleast_2d(np.asarray(x, float)) for x in (A, B, C, D))
        return DiscreteModalSS._zoh_from_arrays(Ad, Bd, Cd, Dd, dt, cond_limit)

    @staticmethod
    def _zoh_from_arrays(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, dt: float,
                         cond_limit: float) -> "DiscreteModalSS":
        n_out, n_in = D.shape
        n = A.shape[0]
        if n == 0:
            return DiscreteModalSS._assemble([], D, n_in, n_out, dt)
        lam, V = np.linalg.eig(A)
        sep = np.abs(lam[:, None] - lam[None, :])
        np.fill_diagonal(sep, np.inf)
        distinct = n == 1 or np.min(sep) > 1e-9 * max(1.0, np.max(np.abs(lam)))
        if distinct and np.linalg.cond(V) < cond_limit:
            Bm = np.linalg.solve(V, B.astype(complex))
            Cm = C @ V
            a, beta = _zoh_scalar(lam, dt)
            blocks = real_modal_blocks(a, Bm * beta[:, None], Cm.T.copy(), pair_on=lam)
            return DiscreteModalSS._assemble(blocks, D, n_in, n_out, dt)
        # dense fallback: expm of the augmented matrix
        M = np.zeros((n + n_in, n + n_in))
        M[:n, :n] = A * dt
        M[:n, n:] = B * dt
        E = scipy.linalg.expm(M)
        return DiscreteModalSS._assemble([(E[:n, :n], E[:n, n:], C)], D, n_in, n_out, dt)

    @staticmethod
    def _assemble(blocks: Sequence[Block], D: ArrayLike, n_in: int, n_out: int, dt: float) -> "DiscreteModalSS":
        if not blocks:
            return DiscreteModalSS(np.zeros((0, 0)), np.zeros((0, n_in)), np.zeros((n_out, 0)),
                                   np.asarray(D, float), np.zeros(0, np.int64), dt)
        A = scipy.linalg.block_diag(*[b[0] for b in blocks])
        B = np.vstack([b[1] for b in blocks])
        C = np.hstack([b[2] for b in blocks])
        sizes = np.array([b[0].shape[0] for b in blocks], np.int64)
        return DiscreteModalSS(np.ascontiguousarray(A), np.ascontiguousarray(B), np.ascontiguousarray(C),
                               np.ascontiguousarray(np.asarray(D, float)), sizes, float(dt))

    def dc_gain(self) -> np.ndarray:
        """Static gain ``C (I − A)⁻¹ B + D``, shape ``[n_out, n_in]``."""
        n = self.n_states
        if n == 0:
            return self.D.copy()
        g: np.ndarray = self.C @ np.linalg.solve(np.eye(n) - self.A, self.B) + self.D
        return g

    def is_stable(self) -> bool:
        """True when every eigenvalue of A is inside the unit circle."""
        if self.n_states == 0:
            return True
        return bool(np.max(np.abs(np.linalg.eigvals(self.A))) < 1.0)

    def packed(self) -> tuple[np.ndarray, np.ndarray]:
        """Arrays for the compiled kernel: A stored row-wise per block (``[n, max_block]``) and offsets."""
        n = self.n_states
        smax = int(self.sizes.max()) if n else 1
        Ablk = np.zeros((max(n, 1), smax))
        offsets = np.zeros(len(self.sizes), np.int64)
        off = 0
        for b, s in enumerate(self.sizes):
            offsets[b] = off
            Ablk[off:off + s, :s] = self.A[off:off + s, off:off + s]
            off += s
        return Ablk, offsets

    def packed_io(self) -> np.ndarray:
        """``[n_states, n_in + n_out]``: row i holds B[i, :] then C[:, i] (one cache line per state)."""
        return np.ascontiguousarray(np.hstack([self.B, self.C.T]), dtype=float)

    @property
    def small_blocks(self) -> bool:
        """True when every block is 1×1 or 2×2 (all modal realisations; not the dense fallback)."""
        return self.n_states == 0 or int(self.sizes.max()) <= 2


def _zoh_scalar(p: ArrayLike, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH of x' = p x + u: a = exp(p dt), beta = (exp(p dt) − 1)/p (→ dt for p = 0)."""
    pc = np.asarray(p, complex)
    a = np.exp(pc * dt)
    small = np.abs(pc * dt) < 1e-12
    beta = np.where(small, dt, np.expm1(pc * dt) / np.where(small, 1.0, pc))
    return a, beta


class LTIFilter:
    """Streaming MIMO filter for a :class:`DiscreteModalSS`; ``process`` blocks of shape ``[N, n_in]``."""

    def __init__(self, ss: DiscreteModalSS) -> None:
        self.ss = ss
        self._Ablk, self._offsets = ss.packed()
        # two inputs, two outputs and 1×1/2×2 blocks (every 2-axis modal filter): the padded two-axis kernel
        self.two_axis = ss.n_in == 2 and ss.n_out == 2 and ss.small_blocks
        if self.two_axis:
            self.W, self.feeds = pad_to_2x2(self._Ablk, ss.packed_io(), self._offsets, ss.sizes)
        self._run: Callable[..., None] | None = None  # the two-axis loop, specialised on first use
        self.x = np.zeros(ss.n_states)

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.ss.n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.ss.n_out

    def reset(self) -> None:
        """All states back to rest."""
        self.x[:] = 0.0

    def process(self, u: np.ndarray) -> np.ndarray:
        """Filter the block ``u`` [N, n_in] → [N, n_out] (state carried between blocks)."""
        u = as_block(u, self.ss.n_in)
        y = np.empty((u.shape[0], self.ss.n_out))
        if self.two_axis:
            if self._run is None:
                self._run = specialised_bank_run(self.W, self.ss.sizes, self.ss.D) or bank_run_2x2
            self._run(self.W, self._offsets, self.ss.sizes, self.feeds, self.ss.D, self.x, u, y)
        else:
            bank_run(self._Ablk, self._offsets, self.ss.sizes, self.ss.B, self.ss.C, self.ss.D, self.x, u, y)
        return y

    def fused_part(self) -> FusedPart | None:
        """This filter's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`): two-axis banks only."""
        if not self.two_axis:
            return None
        return FusedPart(BANK, (self.W, self.feeds, np.ascontiguousarray(self.ss.D), self._offsets, self.ss.sizes),
                         (self.x,))

    def settle_to(self, u_const: np.ndarray) -> None:
        """Put the state at its steady state for a constant input (for bumpless start from a held value)."""
        n = self.ss.n_states
        if n:
            self.x[:] = np.linalg.solve(np.eye(n) - self.ss.A, self.ss.B @ np.asarray(u_const, float))


class FilterStage:
    """A stage that is one :class:`LTIFilter` (``self.filter``): shape, ``process``, ``reset``, ``state`` /
    ``load_state`` (the modal state ``x``) and the fused part are the filter's."""

    filter: LTIFilter

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.filter.n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.filter.n_out

    def reset(self) -> None:
        """All states back to rest."""
        self.filter.reset()

    def process(self, block: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        return self.filter.process(block)

    def state(self) -> dict[str, np.ndarray]:
        """The filter state ``x`` (modal coordinates of ``filter.ss``), a copy."""
        return {"x": self.filter.x.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        self.filter.x[:] = state["x"]

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`), None if not fusable."""
        return self.filter.fused_part()


# ----------------------------------------------------------------------------------------------------------------
# Bumpless state transfer between two modal realisations
# ----------------------------------------------------------------------------------------------------------------

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


def transfer_linear_state(ss_old: DiscreteModalSS, x_old: np.ndarray, ss_new: DiscreteModalSS,
                          u_last: np.ndarray | None = None, rtol: float = 1e-9) -> tuple[np.ndarray, int]:
    """State for ``ss_new`` continuing ``ss_old`` in state ``x_old``: the transfer that makes a swap of linear stages
    bumpless.

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

    Notes
    -----
    Two steps:

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
