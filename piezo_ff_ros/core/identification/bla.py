"""Linear MIMO dynamics from periodic (multisine) voltage records: a parametric best linear approximation.

For records a Bouc-Wen stage cannot follow — broadband multisines up to near the Nyquist frequency, such as the
CubeSpec fine steering mirror set (3 × 3, 6400 Hz, random-phase multisines to 3 kHz) — the stage is identified as
one linear system ``U [V] → Y [m]``:

1. the nonparametric FRF ``G_k`` per frequency bin from the periodic steady state (last period) of every fitting
   realization, least squares over the realizations (``G_k = Y_k·U_k⁺``; the best linear approximation of a
   weakly nonlinear system under random-phase multisines);
2. the poles of a discrete-time state space fitted to ``G_k`` on the excited bins by the frequency-domain subspace
   algorithm (McKelvey, Akçay, Ljung, IEEE TAC 1996: ``A`` from the shift structure of the extended observability
   range); poles outside the unit circle are reflected in, poles far below the lowest excited bin (the DC bin is
   not excited) and real poles at the Nyquist frequency are dropped; then, for those poles, every entry's residues
   by linear least squares on ``G_k`` (strictly proper: the config's G_L has no direct term);
3. the model in the config's form: continuous modes whose exact ZOH is the fitted discrete model (the core
   simulates a G_L entry with the ZOH of its poles, so the fitted model is reproduced), ``Dp`` = the real part of
   its gain at the lowest excited bin (the static gain the feedforward inverts when hysteresis is off) and
   ``G_L(s) = G(s)·Dp⁻¹`` per entry as a factored transfer function (poles, invariant zeros, gain matched on the
   excited band).

The order is given, or chosen (``auto``) on the fitting data alone: the last fitting realization is held out of
the FRF and the smallest order whose prediction error on it is within 2 % of the best is kept, then the model is
refitted on all realizations.  Why this method: it is the standard non-iterative route to a MIMO model from
periodic data (no local minima, seconds for a 3 × 3 set), and it needs only numpy/scipy.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg

from ..config import BoucWenConfig, DynamicsConfig
from ..jsonable import JsonResult
from ..recording.run import RunData
from ..transfer import FactoredTF, TFMatrix

__all__ = ["LinearDynamicsFit", "identify_linear_dynamics", "periodic_steady_state", "broadband_fraction",
           "ORDERS_AUTO"]

#: orders the automatic search tries (the published BLA of the fine steering mirror: 28)
ORDERS_AUTO = tuple(range(8, 53, 4))
#: largest pole radius kept (discrete): slower poles are pulled to it
_MAX_RADIUS = 1.0 - 1e-6
#: poles slower than this fraction of the lowest excited frequency are dropped (undetermined by the records)
_SLOWEST = 0.1


@dataclass(frozen=True)
class LinearDynamicsFit(JsonResult):
    """An identified linear stage: ``hysteresis`` (Dp only) and ``config`` (G_L), orders and facts.

    Attributes
    ----------
    order : int
        State dimension of the discrete model.
    fit_train, fit_validation : dict
        MATLAB ``compare`` fit [%] per output on the fitting / held-out runs' last period (simulated from rest over
        all periods); empty without held-out runs.
    orders_tried : dict
        ``auto``: relative prediction error on the held-out fitting realization per order.
    info : dict
        Facts of the fit (bins, realizations, conversion error).
    """

    order: int
    fit_train: dict[str, float]
    fit_validation: dict[str, float]
    orders_tried: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    hysteresis: BoucWenConfig | None = field(default=None, metadata={"json": False})
    config: DynamicsConfig | None = field(default=None, metadata={"json": False})


def broadband_fraction(u: np.ndarray) -> float:
    """RMS of the sample-to-sample change of ``u`` over the RMS of ``u`` about its mean (largest channel).

    Slow hysteresis sines give ~2π·f/fs (1e-4 … 0.05); a multisine up to near the Nyquist frequency ≈ 1 or more.
    """
    u = np.asarray(u, float)
    du = np.sqrt(np.mean(np.diff(u, axis=0) ** 2, axis=0))
    su = np.sqrt(np.mean((u - u.mean(axis=0)) ** 2, axis=0))
    ok = su > 0
    return float(np.max(du[ok] / su[ok])) if np.any(ok) else 0.0


def periodic_steady_state(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The last period ``(u, y)`` of a periodic record (``meta['periods'] ≥ 2``, ``meta['period_samples']``).

    Raises
    ------
    ValueError
        The run says nothing of its periods, or has one only (no steady state to take).
    """
    n, per = run.meta.get("period_samples"), run.meta.get("periods")
    if not n or not per or int(per) < 2 or int(n) * int(per) != len(run):
        raise ValueError(f"run {run.meta.get('experiment', '?')}: linear dynamics from voltage records need periodic "
                         "records of ≥ 2 periods (meta periods / period_samples, as the u_/y_ .npy importer sets)")
    n = int(n)
    return np.asarray(run.u[-n:], float), np.asarray(run.y[-n:], float)


def _spectra(runs: Sequence[RunData]) -> tuple[np.ndarray, np.ndarray]:
    """``U, Y``: rfft of the last periods, ``[bins, channels, realizations]``."""
    us, ys = zip(*(periodic_steady_state(r) for r in runs))
    return np.fft.rfft(np.stack(us, axis=2), axis=0), np.fft.rfft(np.stack(ys, axis=2), axis=0)


def _excited(U: np.ndarray) -> np.ndarray:
    """Bins that carry excitation (above 1 % of the median of the bins that do); never DC, whose content is the
    records' offsets (sensor zero, amplifier bias), not dynamics."""
    nU = np.linalg.norm(U, axis=(1, 2))
    nU[0] = 0.0
    nz = nU[nU > 0]
    return (nU > 1e-2 * np.median(nz)) if len(nz) else np.zeros(len(nU), bool)


def _frf(U: np.ndarray, Y: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """``G_k = Y_k U_k⁺`` on ``bins`` (least squares over realizations)."""
    G: np.ndarray = Y[bins] @ np.linalg.pinv(U[bins])
    return G


def _subspace(G: np.ndarray, w: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``A, C`` of order ``n`` from FRF samples ``G [M, p, m]`` at ``w`` [rad/sample] (McKelvey et al. 1996)."""
    M, p, m = G.shape
    q = max(2 * n // 3 + 2, 12)
    while q * p <= n:
        q += 1
    z = np.exp(1j * w)
    Gb = np.empty((q * p, M * m), complex)
    Wb = np.empty((q * m, M * m), complex)
    eye = np.broadcast_to(np.eye(m), (M, m, m))
    for i in range(q):
        zi = (z ** i)[:, None, None]
        Gb[i * p:(i + 1) * p] = (G * zi).transpose(1, 0, 2).reshape(p, M * m)
        Wb[i * m:(i + 1) * m] = (eye * zi).transpose(1, 0, 2).reshape(m, M * m)
    H = np.vstack([np.hstack([Wb.real, Wb.imag]), np.hstack([Gb.real, Gb.imag])])
    R = np.asarray(scipy.linalg.qr(H.T, mode="economic")[1]).T     # the square triangular factor only
    Us = np.linalg.svd(R[q * m:, q * m:], full_matrices=False)[0]
    O = Us[:, :n]
    A = np.linalg.lstsq(O[:-p], O[p:], rcond=None)[0]
    return _real_modal(A, O[:p], float(np.min(w)))


def _real_modal(A: np.ndarray, C: np.ndarray, w_min: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, C)`` in real block-diagonal modal form, with poles outside the unit circle reflected into it (kept
    distinct: the config's modal form needs distinct poles), at most at radius ``_MAX_RADIUS``, and
    real poles on the negative axis dropped (a mode at the Nyquist frequency, outside any excited band, which no
    continuous-time mode reproduces under ZOH)."""
    lam, V = np.linalg.eig(A)
    r = np.abs(lam)
    lam = np.where(r > 1.0, 1.0 / np.conj(np.where(r > 1.0, lam, 1.0)), lam)
    r = np.abs(lam)
    lam = np.where(r > _MAX_RADIUS, lam / r * _MAX_RADIUS * (1.0 - 1e-9 * np.arange(len(lam))), lam)
    real = np.abs(lam.imag) <= 1e-12 * np.maximum(1.0, r)
    # poles far slower than the lowest excited frequency are not determined by the records (the DC bin is not
    # excited): dropped, as modes at the Nyquist frequency
    keep = ~(real & (lam.real <= 0)) & (np.abs(np.log(lam.astype(complex))) >= _SLOWEST * w_min)
    blocks, cols = [], []
    for i in np.nonzero(keep)[0]:
        if real[i]:
            blocks.append(np.array([[lam[i].real]]))
            cols.append(V[:, [i]].real)
        elif lam[i].imag > 0:   # one of each pair: basis (Re v, Im v), block [[a, b], [−b, a]]
            a, b = lam[i].real, lam[i].imag
            blocks.append(np.array([[a, b], [-b, a]]))
            cols.append(np.column_stack([V[:, i].real, V[:, i].imag]))
    return scipy.linalg.block_diag(*blocks), C @ np.hstack(cols)


def _poles(A: np.ndarray, dt: float) -> np.ndarray:
    """Continuous poles of the discrete ``A`` (real block-diagonal: exact conjugate pairs) under the exact ZOH
    inverse, ``p = log(λ)/dt``: the real ones and one of each pair (positive imaginary part)."""
    lam = np.linalg.eigvals(A)
    p = np.log(lam.astype(complex)) / dt
    real = np.abs(p.imag) <= 1e-9 * np.maximum(1.0, np.abs(p))
    return np.concatenate([p[real].real.astype(complex), p[~real & (p.imag > 0)]])


def _basis(p: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Real-coefficient basis of the ZOH responses of the modes ``p`` at ``z = e^{iw}``, ``[len(w), n_states]``:
    a real pole gives ``β/(z − λ)`` (``λ = e^{p·dt}``, ``β = (λ − 1)/p``), a pair gives the sum and i × the difference
    of its two (so real coefficients are the real and imaginary part of the pair's residue)."""
    z = np.exp(1j * w)[:, None]
    cols = []
    for pl in p:
        lam = np.exp(pl * dt)
        phi = ((lam - 1.0) / pl) / (z[:, 0] - lam)
        if pl.imag == 0:
            cols.append(phi)
        else:
            lc = np.conj(lam)
            phic = ((lc - 1.0) / np.conj(pl)) / (z[:, 0] - lc)
            cols += [phi + phic, 1j * (phi - phic)]
    return np.column_stack(cols)


def _residues(p: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Complex residue matrices ``R [n_modes, out, in]`` of ``p`` from the basis coefficients of :func:`_basis`."""
    out, i = [], 0
    for pl in p:
        if pl.imag == 0:
            out.append(coef[i].astype(complex))
            i += 1
        else:   # r·φ + r̄·φ̄ = Re r·(φ + φ̄) + Im r·i(φ − φ̄)
            out.append(coef[i] + 1j * coef[i + 1])
            i += 2
    return np.array(out)


def _response(p: np.ndarray, coef: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """The model's discrete (ZOH) frequency response at ``w``, ``[len(w), out, in]``."""
    G: np.ndarray = np.einsum("kn,nij->kij", _basis(p, w, dt), coef)
    return G


def _fit_order(U: np.ndarray, Y: np.ndarray, bins: np.ndarray, N: int, n: int, dt: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Poles (subspace, order ``n``) and, for them, every entry's residues by linear least squares on the FRF
    (each entry its own residues: the config holds every entry with all the poles anyway; better than the
    subspace's rank-one ``C·B``, e.g. 0.043 vs 0.056 relative test error at 300 mV, order 36)."""
    G = _frf(U, Y, bins)
    w = 2 * np.pi * bins / N
    A, _ = _subspace(G, w, n)
    p = _poles(A, dt)
    X = _basis(p, w, dt)
    T = G.reshape(len(w), -1)
    coef = np.linalg.lstsq(np.vstack([X.real, X.imag]), np.vstack([T.real, T.imag]), rcond=None)[0]
    return p, coef.reshape(X.shape[1], G.shape[1], G.shape[2])


def _factored(p: np.ndarray, r: np.ndarray, s_band: np.ndarray) -> FactoredTF:
    """``Σ r_l/(s − p_l)`` (conjugate-closed) as a :class:`FactoredTF`: invariant zeros of the modal realisation,
    the gain matched to the modal sum over ``s_band``."""
    n = len(p)
    if not np.any(r):
        return FactoredTF(0.0)
    # zeros: finite generalized eigenvalues of the Rosenbrock pencil [[diag p, r], [1ᵀ, 0]] − s·[[I, 0], [0, 0]]
    M = np.zeros((n + 1, n + 1), complex)
    M[:n, :n] = np.diag(p)
    M[:n, n] = r
    M[n, :n] = 1.0
    E = np.zeros((n + 1, n + 1))
    E[:n, :n] = np.eye(n)
    z = scipy.linalg.eigvals(M, E)
    scale = float(np.max(np.abs(p)))
    z = z[np.isfinite(z) & (np.abs(z) < 1e4 * scale)]       # far zeros act as a constant over the band
    zr = z[np.abs(z.imag) <= 1e-7 * np.maximum(1.0, np.abs(z))].real
    zc = z[z.imag > 1e-7 * np.maximum(1.0, np.abs(z))]
    pr = p[np.abs(p.imag) <= 1e-9 * np.maximum(1.0, np.abs(p))].real
    pc = p[p.imag > 1e-9 * np.maximum(1.0, np.abs(p))]
    num = tuple((1.0, float(-x)) for x in zr) + tuple((1.0, float(-2 * c.real), float(abs(c) ** 2)) for c in zc)
    den = tuple((1.0, float(-x)) for x in pr) + tuple((1.0, float(-2 * c.real), float(abs(c) ** 2)) for c in pc)
    shape = FactoredTF(1.0, num, den).eval(s_band)
    target = np.sum(r[None, :] / (s_band[:, None] - p[None, :]), axis=1)
    k = float(np.real(np.vdot(shape, target) / np.vdot(shape, shape)))
    return FactoredTF(k, num, den)


def _to_config(p: np.ndarray, coef: np.ndarray, dt: float, w_band: np.ndarray, axes: Sequence[str]
               ) -> tuple[BoucWenConfig, DynamicsConfig, dict[str, Any]]:
    """``Dp`` and ``G_L = G·Dp⁻¹`` of the model (poles ``p``, basis coefficients ``coef``): continuous modes whose
    exact ZOH is the fitted discrete model."""
    R = _residues(p, coef)                                     # [modes, out, in]
    pairs = p.imag != 0
    pa = np.concatenate([p, np.conj(p[pairs])])               # conjugate-closed
    Ra = np.concatenate([R, np.conj(R[pairs])])
    s_band = 1j * w_band / dt

    def cont(s: np.ndarray, Rm: np.ndarray) -> np.ndarray:
        out: np.ndarray = np.einsum("kn,nij->kij", 1.0 / (s[:, None] - pa[None, :]), Rm)
        return out

    Dp = np.real(cont(s_band[:1], Ra)[0])
    RL = Ra @ np.linalg.inv(Dp)
    n_ax = R.shape[1]
    entries = [[_factored(pa, RL[:, i, j], s_band) for j in range(n_ax)] for i in range(n_ax)]
    tfm = TFMatrix.from_nested(entries)
    # the conversion's error over the band, relative to each entry's largest response
    modal = cont(s_band, RL)
    err = max(float(np.max(np.abs(tfm[i, j].eval(s_band) - modal[:, i, j])) / np.max(np.abs(modal[:, i, j])))
              for i in range(n_ax) for j in range(n_ax))
    zero = tuple(tuple(0.0 for _ in range(n_ax)) for _ in range(n_ax))
    hyst = BoucWenConfig(Dp=tuple(tuple(float(v) for v in row) for row in Dp), A=zero, B=zero, Gamma=zero)
    return hyst, DynamicsConfig(tfm).validate(axes), {"conversion_error": err}


def _fit_percent_last_period(runs: Sequence[RunData], simulate: Callable[[np.ndarray], np.ndarray],
                             axes: Sequence[str]) -> tuple[dict[str, float], dict[str, float]]:
    """MATLAB fit [%] per output and ``{rmse, rms}`` [m] over the runs' last periods, simulated from rest."""
    from .goodness_of_fit import fit_percent

    ys, yh = [], []
    for r in runs:
        n = int(r.meta["period_samples"])
        ys.append(np.asarray(r.y[-n:], float))
        yh.append(simulate(np.asarray(r.u, float))[-n:])
    y, h = np.vstack(ys), np.vstack(yh)
    f = fit_percent(y, h)
    return ({a: round(float(v), 3) for a, v in zip(axes, f)},
            {"rmse": float(np.sqrt(np.mean((y - h) ** 2))), "rms": float(np.sqrt(np.mean(y ** 2)))})


def identify_linear_dynamics(runs: Sequence[RunData], validation: Sequence[RunData] = (), order: int | str = "auto",
                             axes: Sequence[str] | None = None, progress: Callable[[str], None] | None = None,
                             ) -> LinearDynamicsFit:
    """Identify ``U → Y`` as ``G_L(s)·Dp`` from periodic voltage records (module docstring).

    Parameters
    ----------
    runs, validation : sequences of RunData
        Fitting / held-out periodic records (``meta['periods'] ≥ 2``, ``meta['period_samples']``), same axes.
    order : int or 'auto'
        State dimension of the discrete model (shared by every entry).
    axes : sequence of str, optional
        Axis names (default the runs').
    progress : callable, optional
        Progress lines.

    Returns
    -------
    LinearDynamicsFit
        ``hysteresis`` (Dp, no hysteresis) and ``config`` (G_L); fits on the last period of each run, simulated
        from rest through the config's own G_L (what the written config will do).

    Raises
    ------
    ValueError
        Records that are not periodic, of different period or sample rate, or without excitation.
    """
    from ..models.dynamics import DynamicsModel

    say = progress or (lambda s: None)
    if not runs:
        raise ValueError("linear dynamics: no fitting runs")
    axes = tuple(axes or runs[0].axes)
    N = len(periodic_steady_state(runs[0])[0])
    dt = runs[0].dt
    for r in list(runs) + list(validation):
        if len(periodic_steady_state(r)[0]) != N or abs(r.dt - dt) > 1e-9 * dt:
            raise ValueError(f"run {r.meta.get('experiment', '?')}: periods of {len(periodic_steady_state(r)[0])} "
                             f"samples at {1 / r.dt:g} Hz, the first run's {N} at {1 / dt:g} Hz: one set at a time")
    U, Y = _spectra(runs)
    bins = np.nonzero(_excited(U))[0]
    if len(bins) < 2 * len(axes):
        raise ValueError("linear dynamics: the records excite too few frequency bins")
    if U.shape[2] < len(axes):
        raise ValueError(f"linear dynamics: {U.shape[2]} realization(s) for {len(axes)} inputs: the FRF needs at "
                         "least as many realizations as inputs")
    tried: dict[str, float] = {}
    if order == "auto":
        if U.shape[2] <= len(axes):
            raise ValueError("linear dynamics: order 'auto' holds a realization out and needs more realizations "
                             "than inputs; give --dynamics-order")
        Ufit, Yfit, Uho, Yho = U[:, :, :-1], Y[:, :, :-1], U[bins, :, -1], Y[bins, :, -1]
        w = 2 * np.pi * bins / N
        for n in ORDERS_AUTO:
            pn, cn = _fit_order(Ufit, Yfit, bins, N, n, dt)
            E = Yho - np.einsum("kij,kj->ki", _response(pn, cn, w, dt), Uho)
            tried[str(n)] = float(np.linalg.norm(E) / np.linalg.norm(Yho))
            say(f"dynamics: linear order {n}: relative error on the held-out fitting realization {tried[str(n)]:.4f}")
        best = min(tried.values())
        n_sel = min(int(k) for k, v in tried.items() if v <= 1.02 * best)
    else:
        if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
            raise ValueError(f"--dynamics-order: linear dynamics take one order for the whole model (an integer ≥ 1 "
                             f"or auto), got {order!r}")
        n_sel = int(order)
        if n_sel < 1:
            raise ValueError(f"--dynamics-order: expected an integer ≥ 1 or auto, got {order!r}")
    poles, coef = _fit_order(U, Y, bins, N, n_sel, dt)
    w_band = 2 * np.pi * bins / N
    hyst, dyn, facts = _to_config(poles, coef, dt, w_band, axes)
    Dp = np.array(hyst.Dp, float)

    def simulate(u: np.ndarray) -> np.ndarray:
        return np.asarray(DynamicsModel(dyn, dt).process(u @ Dp.T))

    fit_tr, _ = _fit_percent_last_period(runs, simulate, axes)
    fit_val, _ = _fit_percent_last_period(validation, simulate, axes) if validation else ({}, {})
    say(f"dynamics: linear model of order {n_sel} ({len(bins)} excited bins, {U.shape[2]} realizations); fit "
        f"{fit_val or fit_tr} %")
    return LinearDynamicsFit(order=n_sel, fit_train=fit_tr, fit_validation=fit_val, orders_tried=tried,
                             info={"method": "nonparametric FRF (last period, LS over realizations) + "
                                             "frequency-domain subspace poles (McKelvey 1996) + per-entry "
                                             "residues by LS, exact ZOH modes",
                                   "bins": int(len(bins)), "realizations": int(U.shape[2]), **facts},
                             hysteresis=hyst, config=dyn)


def heldout_rmse(cfg_dynamics: DynamicsConfig, Dp: np.ndarray, runs: Sequence[RunData], axes: Sequence[str]
                 ) -> dict[str, float]:
    """Test figures in the published BLA's metric: RMSE [m] over the runs' last periods (the first is the
    initialization window), all realizations and channels, and NRMSE = RMSE / RMS(y) [%]."""
    from ..models.dynamics import DynamicsModel

    dt = runs[0].dt
    _, e = _fit_percent_last_period(
        runs, lambda u: np.asarray(DynamicsModel(cfg_dynamics, dt).process(u @ np.asarray(Dp).T)), axes)
    return {"rmse": e["rmse"], "rms": e["rms"], "nrmse_percent": 100.0 * e["rmse"] / e["rms"]}
