"""Transfer functions as the papers print them: factored SISO entries, their matrices and real modal blocks (pure).

:class:`FactoredTF` keeps every transfer function in factored form (the paper's are order 9 with coefficients
spanning 1e-7 … 1e9: expanded polynomials lose most of their digits) and splits it into its modes (partial
fractions at distinct poles); :class:`TFMatrix` is a matrix of them; :func:`real_modal_blocks` groups complex modes
into real 1×1 / 2×2 blocks and :func:`continuous_modal_realisation` stacks a matrix's modes into one real
block-diagonal state space.  These are values: the configuration describes its stages with them, and
:mod:`piezo_ff_ros.core.lti` discretises and runs them.  Nothing here imports the rest of the package.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

__all__ = ["Factor", "Block", "FactoredTF", "TFMatrix", "real_modal_blocks", "continuous_modal_realisation"]

#: conjugate pairing tolerance (relative imaginary part below which a mode counts as real)
_PAIR_TOL = 1e-9

#: one polynomial factor in s, highest power first
Factor = tuple[float, ...]
#: a real modal block (A_blk, B_blk, C_blk)
Block = tuple[np.ndarray, np.ndarray, np.ndarray]


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

def real_modal_blocks(p: ArrayLike, b_rows: np.ndarray, c_cols: np.ndarray,
                            pair_on: ArrayLike | None = None) -> list[Block]:
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
    blocks: list[Block] = []
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
            for A, B, C in real_modal_blocks(p, brow, ccol):
                As.append(A)
                Bs.append(B)
                Cs.append(C)
    A = scipy.linalg.block_diag(*As) if As else np.zeros((0, 0))
    B = np.vstack(Bs) if Bs else np.zeros((0, n_in))
    C = np.hstack(Cs) if Cs else np.zeros((n_out, 0))
    return A, B, C, D
