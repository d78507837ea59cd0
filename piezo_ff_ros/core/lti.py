"""Linear time-invariant building blocks: factored transfer functions and exact ZOH streaming filters.

Why not ``scipy.signal.cont2discrete`` + ``tf2sos``: the paper's transfer functions are order 9 with coefficients
spanning 1e-7 … 1e9; expanded polynomials lose most of their digits.  Instead every transfer function is kept in
factored form, split into its modes (partial fractions at distinct poles), and each mode is discretised exactly by
zero-order hold (``a = exp(pT)``, ``b = expm1(pT)/p``).  The result is a block-diagonal real state space (1×1 and
2×2 blocks) run by one compiled loop with carried state: bit-identical whatever the block split.

Continuous MIMO state spaces (the H∞ controller) go through the same modal route when their eigenvectors are
well conditioned, otherwise through a dense ZOH (``scipy.linalg.expm``) in a single block.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from .kernels.fused import BANK, FusedPart
from .kernels.modal import bank_run, bank_run_2x2, pad_to_2x2
from .kernels.specialise import specialised_bank_run
from .stage import StageState, as_block

__all__ = [
    "FactoredTF",
    "TFMatrix",
    "DiscreteModalSS",
    "LTIFilter",
    "FilterStage",
    "static_gain",
]

_PAIR_TOL = 1e-9


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

#: one polynomial factor in s, highest power first
Factor = tuple[float, ...]
#: a real modal block (A_blk, B_blk, C_blk)
_Block = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class FactoredTF:
    """A SISO transfer function ``k · Π num_factors(s) / Π den_factors(s)``.

    Each factor is a polynomial in s, highest power first (``[1, a]`` is ``s + a``, ``[1, b, c]`` is
    ``s² + b s + c``), exactly as papers print them.
    """

    gain: float
    num: tuple[Factor, ...] = ()
    den: tuple[Factor, ...] = ()

    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> "FactoredTF":
        """From ``{k (or gain): float, num: [[…], …], den: [[…], …]}`` (the YAML form).

        Parameters
        ----------
        d : mapping
            The entry; missing keys mean gain 0 and no factors.

        Returns
        -------
        FactoredTF
        """
        return FactoredTF(float(d.get("k", d.get("gain", 0.0))),
                          tuple(tuple(float(c) for c in f) for f in d.get("num", [])),
                          tuple(tuple(float(c) for c in f) for f in d.get("den", [])))

    def to_dict(self) -> dict[str, Any]:
        """The YAML form (see :meth:`from_dict`)."""
        return {"k": float(self.gain), "num": [list(f) for f in self.num], "den": [list(f) for f in self.den]}

    # -- algebra -------------------------------------------------------------------------------------------------
    def zeros(self) -> np.ndarray:
        """Roots of the numerator factors (complex)."""
        return _roots_of_factors(self.num)

    def poles(self) -> np.ndarray:
        """Roots of the denominator factors (complex)."""
        return _roots_of_factors(self.den)

    @property
    def order(self) -> int:
        """Degree of the denominator."""
        return sum(len(f) - 1 for f in self.den)

    @property
    def relative_degree(self) -> int:
        """Degree of the denominator minus degree of the numerator."""
        return self.order - sum(len(f) - 1 for f in self.num)

    def is_zero(self) -> bool:
        """True for the zero transfer function (gain 0)."""
        return self.gain == 0.0

    def eval(self, s: ArrayLike) -> np.ndarray:
        """Frequency response at complex points ``s`` (array)."""
        sv = np.asarray(s, dtype=complex)
        out: np.ndarray = np.full(sv.shape, self.gain, dtype=complex)
        for f in self.num:
            out = out * np.polyval(f, sv)
        for f in self.den:
            out = out / np.polyval(f, sv)
        return out

    def dc_gain(self) -> float:
        """``H(0)``."""
        return float(np.real(self.eval(np.array([0.0]))[0]))

    def leading_gain(self) -> float:
        """The overall gain once every factor is made monic (``k · Π lead(num) / Π lead(den)``)."""
        g = self.gain
        for f in self.num:
            g *= f[0]
        for f in self.den:
            g /= f[0]
        return g

    def duplicated_factors(self) -> list[Factor]:
        """Factors printed both in the numerator and the denominator (they cancel)."""
        den = list(self.den)
        dup = []
        for f in self.num:
            if f in den:
                dup.append(f)
                den.remove(f)
        return dup

    def cancelled(self) -> "FactoredTF":
        """Same transfer function with factors that appear verbatim in num and den removed."""
        num, den = list(self.num), list(self.den)
        for f in self.duplicated_factors():
            num.remove(f)
            den.remove(f)
        return FactoredTF(self.gain, tuple(num), tuple(den))

    def scaled(self, factor: float) -> "FactoredTF":
        """The same transfer function with its gain multiplied by ``factor``."""
        return FactoredTF(self.gain * factor, self.num, self.den)

    def is_stable(self) -> bool:
        """True when every pole is in the open left half-plane."""
        p = self.poles()
        return bool(np.all(p.real < 0.0))

    # -- modes -------------------------------------------------------------------------------------------------
    def modes(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Poles ``p``, residues ``c`` and direct term ``d`` with ``H(s) = d + Σ c_i/(s − p_i)``.

        Requires distinct poles (after cancelling verbatim duplicates).
        """
        tf = self.cancelled()
        p = tf.poles()
        z = tf.zeros()
        k = tf.leading_gain()
        if len(z) > len(p):
            raise ValueError("improper transfer function (more zeros than poles)")
        d = k if len(z) == len(p) else 0.0
        if self.gain == 0.0:
            return np.zeros(0, complex), np.zeros(0, complex), 0.0
        if len(p) == 0:
            return np.zeros(0, complex), np.zeros(0, complex), float(k)
        sep = np.abs(p[:, None] - p[None, :])
        np.fill_diagonal(sep, np.inf)
        if np.any(sep < 1e-9 * np.maximum(1.0, np.abs(p))[:, None]):
            raise ValueError("repeated poles: modal discretisation needs distinct poles")
        c = np.empty(len(p), complex)
        for i, pi in enumerate(p):
            c[i] = k * np.prod(pi - z) / np.prod(np.delete(pi - p, i))
        return p, c, float(d)


def _roots_of_factors(factors: Sequence[Factor]) -> np.ndarray:
    roots = [np.roots(np.asarray(f, float)) for f in factors if len(f) > 1]
    return np.concatenate(roots).astype(complex) if roots else np.zeros(0, complex)


@dataclass(frozen=True)
class TFMatrix:
    """A matrix of SISO :class:`FactoredTF` entries, ``entries[i][j]`` from input j to output i."""

    entries: tuple[tuple[FactoredTF, ...], ...]

    @staticmethod
    def from_nested(rows: Sequence[Sequence[FactoredTF]]) -> "TFMatrix":
        """From rows of entries (``rows[i][j]``: input j to output i)."""
        return TFMatrix(tuple(tuple(r) for r in rows))

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_out, n_in)``."""
        return len(self.entries), len(self.entries[0])

    def __getitem__(self, ij: tuple[int, int]) -> FactoredTF:
        i, j = ij
        return self.entries[i][j]

    def eval(self, s: ArrayLike) -> np.ndarray:
        """Frequency response, shape ``[len(s), n_out, n_in]``."""
        sv = np.atleast_1d(np.asarray(s, complex))
        n, m = self.shape
        out = np.empty((len(sv), n, m), complex)
        for i in range(n):
            for j in range(m):
                out[:, i, j] = self.entries[i][j].eval(sv)
        return out

    def dc_gain(self) -> np.ndarray:
        """``H(0)``, shape ``[n_out, n_in]``."""
        g: np.ndarray = np.real(self.eval(np.array([0.0]))[0])
        return g

    def to_control(self) -> Any:
        """A ``control.StateSpace`` realisation: the per-entry modal realisations stacked (not minimal)."""
        import control

        A, B, C, D = continuous_modal_realisation(self)
        return control.ss(A, B, C, D)


# ----------------------------------------------------------------------------------------------------------------
# Continuous modal realisation (real block-diagonal) of a TF matrix
# ----------------------------------------------------------------------------------------------------------------

def _real_blocks_from_modes(p: ArrayLike, b_rows: np.ndarray, c_cols: np.ndarray,
                            pair_on: ArrayLike | None = None) -> list[_Block]:
    """Group complex modes into real 1×1 / 2×2 blocks.

    ``p[i]`` is the (continuous or discrete) eigenvalue of mode i, ``b_rows[i]`` (n_in,) and ``c_cols[i]`` (n_out,)
    its complex input and output vectors.  Which modes are real and which form conjugate pairs is decided on
    ``pair_on`` (default ``p``): for a discretised bank pass the *continuous* poles, because a mode that decays
    within one sample has ``a = e^{pT} ≈ 0`` — it looks real although its b and c are complex, and treating it as
    real would drop their imaginary parts (the ZOH defect below ~500 Hz).
    Returns lists of (A_blk, B_blk, C_blk).
    """
    p = np.asarray(p, complex)
    q = p if pair_on is None else np.asarray(pair_on, complex)
    blocks: list[_Block] = []
    used = np.zeros(len(p), bool)
    for i in range(len(p)):
        if used[i]:
            continue
        if abs(q[i].imag) <= _PAIR_TOL * max(1.0, abs(q[i])):
            used[i] = True
            blocks.append((np.array([[p[i].real]]), np.real(b_rows[i])[None, :], np.real(c_cols[i])[:, None]))
            continue
        # find its conjugate partner
        cand = [j for j in range(len(p)) if not used[j] and j != i]
        j = min(cand, key=lambda j: abs(q[j] - np.conj(q[i])))
        used[i] = used[j] = True
        if q[i].imag < 0:
            i, j = j, i
        pi = p[i]
        bi, ci = b_rows[i], c_cols[i]
        # complex mode x' = p x + b u, y = 2 Re(c x): real state [Re x, Im x]
        A = np.array([[pi.real, -pi.imag], [pi.imag, pi.real]])
        B = np.vstack([bi.real, bi.imag])
        C = np.column_stack([2 * ci.real, -2 * ci.imag])
        blocks.append((A, B, C))
    return blocks


def continuous_modal_realisation(tfm: TFMatrix) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Real block-diagonal continuous (A, B, C, D) stacking every entry's modes.

    Parameters
    ----------
    tfm : TFMatrix
        The transfer-function matrix (distinct poles per entry).

    Returns
    -------
    A, B, C, D : numpy.ndarray
        The (not minimal) realisation.
    """
    n_out, n_in = tfm.shape
    As: list[np.ndarray] = []
    Bs: list[np.ndarray] = []
    Cs: list[np.ndarray] = []
    D = np.zeros((n_out, n_in))
    for i in range(n_out):
        for j in range(n_in):
            tf = tfm[i, j]
            if tf.is_zero():
                continue
            p, c, d = tf.modes()
            D[i, j] += d
            brow = np.zeros((len(p), n_in), complex)
            brow[:, j] = 1.0
            ccol = np.zeros((len(p), n_out), complex)
            ccol[:, i] = c
            for A, B, C in _real_blocks_from_modes(p, brow, ccol):
                As.append(A)
                Bs.append(B)
                Cs.append(C)
    A = scipy.linalg.block_diag(*As) if As else np.zeros((0, 0))
    B = np.vstack(Bs) if Bs else np.zeros((0, n_in))
    C = np.hstack(Cs) if Cs else np.zeros((n_out, 0))
    return A, B, C, D


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
        """Each SISO entry discretised on its own by exact zero-order hold, stacked."""
        n_out, n_in = tfm.shape
        blocks: list[_Block] = []
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
                blocks += _real_blocks_from_modes(a, brow, ccol, pair_on=p)
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
            blocks = _real_blocks_from_modes(a, Bm * beta[:, None], Cm.T.copy(), pair_on=lam)
            return DiscreteModalSS._assemble(blocks, D, n_in, n_out, dt)
        # dense fallback: expm of the augmented matrix
        M = np.zeros((n + n_in, n + n_in))
        M[:n, :n] = A * dt
        M[:n, n:] = B * dt
        E = scipy.linalg.expm(M)
        return DiscreteModalSS._assemble([(E[:n, :n], E[:n, n:], C)], D, n_in, n_out, dt)

    @staticmethod
    def _assemble(blocks: Sequence[_Block], D: ArrayLike, n_in: int, n_out: int, dt: float) -> "DiscreteModalSS":
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

    def output_now(self) -> np.ndarray:
        """C x (the strictly proper part of the next output)."""
        y: np.ndarray = self.ss.C @ self.x
        return y

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
