"""Continuous-time output-error fitting on a modal parametrisation, by variable projection.

Each SISO entry ``G_ij(s) = Σ c/(s − p)`` is described by its poles: real poles ``p = −exp(θ)`` and complex pairs
``p = −exp(θ_a) ± i·exp(θ_b)`` — stable by construction.  For given poles, each mode's response to the recorded input
is computed *exactly* under zero-order hold (``x[k+1] = e^{pT}x[k] + (e^{pT} − 1)/p·u[k]``, the same discretisation
the core's plant and compensators use), so the residues enter linearly and are solved by linear least squares
(variable projection, Golub & Pereyra); only the poles are searched with ``scipy.optimize.least_squares``.  The
result is strictly proper and stable by construction, converted to the printed factored form (:class:`FactoredTF`).

Why this method: it fits the simulated output (output error — unbiased with white sensor noise, unlike equation
error/ARX), works on any input (steps, PRBS, multisines; several records), keeps each entry with its own poles as
the paper's Box–Jenkins fits do, and needs only numpy/scipy (no MATLAB System Identification Toolbox; no maintained
Python equivalent is installed here).  Initial poles come from ERA/Ho–Kalman (:func:`era_poles`) or from a grid.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.linalg
import scipy.signal
from scipy.optimize import least_squares

from ..jsonable import JsonResult
from ..lti import FactoredTF

#: one factor of a :class:`FactoredTF` polynomial (``(1, a)`` or ``(1, a, b)``)
_Factor = tuple[float, ...]

__all__ = ["ModalFit", "Structure", "EntryModel", "mode_responses", "fit_row", "simulate_row", "era_poles",
           "poles_to_theta", "entry_to_factored"]


@dataclass(frozen=True)
class ModalFit(JsonResult):
    """What an identification of modal transfer-function entries found besides its config (the base of
    :class:`~.creep.CreepFit` and :class:`~.dynamics.DynamicsFit`, which add ``config``).

    Attributes
    ----------
    orders : dict
        Model order per entry.
    fit_train, fit_validation : dict
        Fit [%] per entry on the fitted and the held-out records (empty: no held-out record).
    info : dict
        Facts of the fit.
    """

    orders: dict[str, Any]
    fit_train: dict[str, float]
    fit_validation: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Structure:
    """Pole structure of one entry: ``n_real`` real poles and ``n_pairs`` complex pairs."""

    n_real: int
    n_pairs: int

    @property
    def order(self) -> int:
        """Model order (number of poles)."""
        return self.n_real + 2 * self.n_pairs

    @property
    def n_theta(self) -> int:
        """Number of pole parameters θ."""
        return self.n_real + 2 * self.n_pairs

    @property
    def n_coef(self) -> int:
        """Number of real basis coefficients."""
        return self.n_real + 2 * self.n_pairs


@dataclass
class EntryModel:
    """Poles (real ones, then one of each complex pair with Im > 0) and real coefficients of the mode basis."""

    structure: Structure
    theta: np.ndarray
    coef: np.ndarray

    def poles(self) -> np.ndarray:
        """The continuous poles (real ones, then one per pair with Im > 0) [rad/s]."""
        return theta_to_poles(self.theta, self.structure)

    def to_factored(self) -> FactoredTF:
        """The entry as a :class:`FactoredTF` (real 1st/2nd-order factors)."""
        return entry_to_factored(self.poles(), self.coef, self.structure)


def theta_to_poles(theta: np.ndarray, st: Structure) -> np.ndarray:
    """θ (log magnitudes of the real parts, and of the imaginary parts of pairs) → continuous poles."""
    th = np.asarray(theta, float)
    real = -np.exp(th[:st.n_real])
    pairs = -np.exp(th[st.n_real::2][:st.n_pairs]) + 1j * np.exp(th[st.n_real + 1::2][:st.n_pairs])
    return np.concatenate([real.astype(complex), pairs])


def poles_to_theta(poles: np.ndarray) -> tuple[np.ndarray, Structure]:
    """Stable poles → (θ, structure); unstable/zero real parts are reflected/clipped into the left half plane."""
    p = np.asarray(poles, complex)
    real = [abs(x.real) for x in p if abs(x.imag) <= 1e-9 * max(1.0, abs(x))]
    pairs = [x for x in p if x.imag > 1e-9 * max(1.0, abs(x))]
    th = [np.log(max(r, 1e-12)) for r in real]
    for x in pairs:
        th += [np.log(max(abs(x.real), 1e-9 * abs(x))), np.log(x.imag)]
    return np.array(th, float), Structure(len(real), len(pairs))


def mode_responses(theta: np.ndarray, st: Structure, u: np.ndarray, dt: float) -> np.ndarray:
    """Basis ``[N, n_coef]``: ZOH responses of ``1/(s − p)`` (real p) and Re/Im of ``1/(s − p)`` (pairs)."""
    p = theta_to_poles(theta, st)
    a = np.exp(p * dt)
    small = np.abs(p * dt) < 1e-12
    beta = np.where(small, dt, np.expm1(p * dt) / np.where(small, 1.0, p))
    N = len(u)
    out = np.empty((N, st.n_coef))
    for m in range(st.n_real):
        out[:, m] = scipy.signal.lfilter([0.0, beta[m].real], [1.0, -a[m].real], u)
    for q in range(st.n_pairs):
        m = st.n_real + q
        x = scipy.signal.lfilter(np.array([0.0, beta[m]]), np.array([1.0, -a[m]]), u.astype(complex))
        out[:, st.n_real + 2 * q] = 2.0 * x.real
        out[:, st.n_real + 2 * q + 1] = -2.0 * x.imag
    return out


def _row_basis(thetas: Sequence[np.ndarray], structs: Sequence[Structure], inputs: Sequence[Sequence[np.ndarray]],
               dt: float) -> np.ndarray:
    cols = []
    for th, st, u in zip(thetas, structs, inputs):
        if st.order == 0:
            continue
        cols.append(np.vstack([mode_responses(th, st, uu, dt) for uu in u]))
    return np.hstack(cols) if cols else np.zeros((sum(len(uu) for uu in inputs[0]), 0))


def _split(theta_all: np.ndarray, structs: Sequence[Structure]) -> list[np.ndarray]:
    out: list[np.ndarray] = []
    i = 0
    for st in structs:
        out.append(theta_all[i:i + st.n_theta])
        i += st.n_theta
    return out


def _solve_coef(Phi: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Linear least squares for the residues: normal equations on unit-norm columns (a few columns, thousands of
    rows: ~5× cheaper than an SVD and free of BLAS threading overhead), SVD when they are ill-conditioned."""
    A = Phi[w]
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    G = As.T @ As
    ev = np.linalg.eigvalsh(G)
    if ev[0] > 1e-12 * ev[-1]:
        sol: np.ndarray = np.linalg.solve(G, As.T @ y[w]) / scale
        return sol
    c, *_ = np.linalg.lstsq(As, y[w], rcond=None)
    out: np.ndarray = c / scale
    return out


def fit_row(y_records: Sequence[np.ndarray], u_records: Sequence[Sequence[np.ndarray]],
            structs: Sequence[Structure], theta0s: Sequence[np.ndarray], dt: float,
            mask_records: Sequence[np.ndarray] | None = None, max_nfev: int = 200,
            pole_min: float = 1e-7) -> tuple[list[EntryModel], float]:
    """Fit one output row ``y_i = Σ_j G_ij u_j``.

    Parameters
    ----------
    y_records : list of [N_r] arrays
        The output, one array per record.
    u_records : list (per input j) of lists (per record) of [N_r] arrays
        The inputs.
    structs, theta0s : per input j
        Pole structure and initial θ (order-0 structures mean "no entry").
    mask_records : list of bool [N_r], optional
        Samples that enter the cost (e.g. excluding fast transients).
    pole_min : float
        Smallest pole magnitude (real part of pairs) allowed [rad/s]: poles much slower than the records are long
        are not determined by the data and would set the DC gain arbitrarily.

    Returns
    -------
    list of EntryModel (per input), cost
    """
    y = np.concatenate(y_records)
    w = np.concatenate(mask_records) if mask_records is not None else np.ones(len(y), bool)
    # unit-scale the output: the optimiser's tolerances are absolute (displacements are ~1e-6 m)
    y_scale = float(np.sqrt(np.mean(y[w] ** 2))) or 1.0
    y = y / y_scale
    th0 = np.concatenate([np.asarray(t, float) for t in theta0s]) if theta0s else np.zeros(0)

    def resid(th: np.ndarray) -> np.ndarray:
        Phi = _row_basis(_split(th, structs), structs, u_records, dt)
        if Phi.shape[1] == 0:
            return y[w]  # type: ignore[no-any-return]  # a boolean-mask index of an ndarray is an ndarray
        c = _solve_coef(Phi, y, w)
        r: np.ndarray = Phi[w] @ c - y[w]
        return r if np.all(np.isfinite(r)) else np.full(r.shape, 1e6 * (np.std(y[w]) + 1.0))

    if th0.size:
        # keep poles within a sane band: |p| from pole_min to 1e3/dt
        lo, hi = np.log(pole_min), np.log(1e3 / dt)
        # lsmr trust-region steps: no SVD of the tall Jacobian per iteration (dominant cost otherwise); a single
        # unknown (one real pole: a single-axis creep of order 1) needs the exact solver — scipy's bounded trf
        # takes a 2-D subspace step with lsmr and fails with an IndexError on one variable
        sol = least_squares(resid, np.clip(th0, lo + 1e-6, hi - 1e-6), bounds=(lo, hi), method="trf",
                            x_scale=1.0, max_nfev=max_nfev, xtol=1e-10, ftol=1e-12,
                            tr_solver="lsmr" if th0.size > 1 else "exact")
        th = sol.x
        cost = float(sol.cost)
    else:
        th = th0
        cost = float(0.5 * np.sum(y[w] ** 2))
    thetas = [_separate(t, st) for t, st in zip(_split(th, structs), structs)]
    Phi = _row_basis(thetas, structs, u_records, dt)
    c = _solve_coef(Phi, y, w) * y_scale if Phi.shape[1] else np.zeros(0)
    cost *= y_scale ** 2
    models: list[EntryModel] = []
    i = 0
    for st, t in zip(structs, thetas):
        models.append(EntryModel(st, np.asarray(t), c[i:i + st.n_coef]))
        i += st.n_coef
    return models, cost


def _separate(theta: np.ndarray, st: Structure, rel: float = 1e-4) -> np.ndarray:
    """Nudge coinciding poles of one entry apart (the modal realisation needs distinct poles).

    Two modes that converged onto the same pole carry the same basis column; moving one by ``rel`` (relative)
    changes the response by far less than the fit resolves and the residues are re-solved afterwards.
    """
    th = np.array(theta, float)
    p = theta_to_poles(th, st)
    for a in range(len(p)):
        for b in range(a):
            if abs(p[a] - p[b]) <= rel * max(abs(p[a]), 1e-300):
                k = a if a < st.n_real else st.n_real + 2 * (a - st.n_real)
                th[k] += 5 * rel
                p = theta_to_poles(th, st)
    return th


def simulate_row(models: Sequence[EntryModel], u_inputs: Sequence[np.ndarray], dt: float) -> np.ndarray:
    """``Σ_j G_ij u_j`` for one record (``u_inputs`` list of [N] arrays, one per input)."""
    out = np.zeros(len(u_inputs[0]))
    for m, u in zip(models, u_inputs):
        if m.structure.order:
            out += mode_responses(m.theta, m.structure, u, dt) @ m.coef
    return out


def era_poles(h: np.ndarray, order: int, dt: float, rows: int | None = None) -> np.ndarray:
    """Continuous poles of an order-``order`` ERA (Ho–Kalman) realisation of impulse response ``h[1:]`` (SISO)."""
    h = np.asarray(h, float).ravel()
    L = len(h) - 1
    r = rows or min(L // 2, 400)
    H0 = scipy.linalg.hankel(h[1:r + 1], h[r:2 * r])
    H1 = scipy.linalg.hankel(h[2:r + 2], h[r + 1:2 * r + 1])
    U, s, Vt = np.linalg.svd(H0)
    n = min(order, len(s))
    S = np.diag(1.0 / np.sqrt(s[:n]))
    Ad = S @ U[:, :n].T @ H1 @ Vt[:n].T @ S
    z = np.linalg.eigvals(Ad)
    z = np.where(np.abs(z) < 1e-12, 1e-12, z)
    p = np.log(z.astype(complex)) / dt
    # fold to a stable, conjugate-closed set: one per pair with Im ≥ 0
    p = np.where(p.real >= 0, -np.abs(p.real) - 1e-6 / dt + 1j * p.imag, p)
    keep = [x for x in p if x.imag >= -1e-12 * max(1.0, abs(x))]
    # negative real z (p with Im = π/dt) are sampling artefacts: make them real fast poles
    keep = [complex(x.real, 0.0) if abs(abs(x.imag) - np.pi / dt) < 1e-6 / dt else x for x in keep]
    return np.array(keep, complex)


def entry_to_factored(poles: np.ndarray, coef: np.ndarray, st: Structure) -> FactoredTF:
    """Modal form (poles, real basis coefficients) → :class:`FactoredTF` with real 1st/2nd-order factors."""
    if st.order == 0 or not np.any(coef):
        return FactoredTF(0.0)
    p = np.asarray(poles, complex)
    # real block-diagonal state space
    blocks_A: list[np.ndarray] = []
    Bs: list[float] = []
    Cs: list[float] = []
    for m in range(st.n_real):
        blocks_A.append(np.array([[p[m].real]]))
        Bs.append(1.0)
        Cs.append(coef[m])
    for q in range(st.n_pairs):
        pm = p[st.n_real + q]
        c1, c2 = coef[st.n_real + 2 * q], coef[st.n_real + 2 * q + 1]
        # basis: 2Re(x), −2Im(x) with x' = p x + u  →  y = c1·2Re x − c2·2Im x
        blocks_A.append(np.array([[pm.real, -pm.imag], [pm.imag, pm.real]]))
        Bs += [1.0, 0.0]
        Cs += [2 * c1, -2 * c2]
    A = scipy.linalg.block_diag(*blocks_A)
    B = np.array(Bs, float)[:, None]
    C = np.array(Cs, float)[None, :]
    n = A.shape[0]
    # zeros: numerator polynomial det(sI − A + BC) − det(sI − A) (= C·adj(sI − A)·B), computed with s scaled by
    # the poles' geometric mean so that the coefficients stay O(1) (unscaled they span (10⁴)ⁿ)
    sigma = float(np.exp(np.mean(np.log(np.abs(p) + 1e-300))))
    As, Cscaled = A / sigma, C / sigma
    num_s = np.poly(As - B @ Cscaled) - np.poly(As)
    num_s = num_s[1:]                                   # strictly proper: the sⁿ terms cancel exactly
    big = np.max(np.abs(num_s))
    lead = np.nonzero(np.abs(num_s) > 1e-9 * big)[0]
    num_s = num_s[lead[0]:] if len(lead) else num_s[-1:]
    z = np.roots(num_s) * sigma if len(num_s) > 1 else np.zeros(0, complex)
    scale = max(1.0, float(np.max(np.abs(p))))
    z = z[np.abs(z) < 1e6 * scale]
    zc = _conj_close(z)
    den = _factors(p, st)
    num = _factors_from_roots(zc)
    # gain from a point where the response is well away from poles/zeros
    s0 = 1j * float(np.exp(np.mean(np.log(np.abs(p) + 1e-300)))) + 1e-3
    H = (C @ np.linalg.solve(s0 * np.eye(n) - A, B))[0, 0]
    shape = FactoredTF(1.0, num, den).eval(np.array([s0]))[0]
    k = float(np.real(H / shape))
    return FactoredTF(k, num, den)


def _conj_close(z: np.ndarray) -> list[complex]:
    z = np.asarray(z, complex)
    out: list[complex] = []
    used = np.zeros(len(z), bool)
    for i, zi in enumerate(z):
        if used[i]:
            continue
        used[i] = True
        if abs(zi.imag) <= 1e-8 * max(1.0, abs(zi)):
            out.append(complex(zi.real, 0.0))
            continue
        cand = [j for j in range(len(z)) if not used[j]]
        if cand:
            j = min(cand, key=lambda j: abs(z[j] - np.conj(zi)))
            used[j] = True
        out.append(complex(zi.real, abs(zi.imag)))
    return out


def _factors(p: np.ndarray, st: Structure) -> tuple[_Factor, ...]:
    fs: list[_Factor] = [(1.0, float(-p[m].real)) for m in range(st.n_real)]
    for q in range(st.n_pairs):
        pm = p[st.n_real + q]
        fs.append((1.0, float(-2 * pm.real), float(abs(pm) ** 2)))
    return tuple(fs)


def _factors_from_roots(z: Sequence[complex]) -> tuple[_Factor, ...]:
    fs: list[_Factor] = []
    for zi in z:
        if zi.imag == 0.0:
            fs.append((1.0, float(-zi.real)))
        else:
            fs.append((1.0, float(-2 * zi.real), float(abs(zi) ** 2)))
    return tuple(fs)
