"""Simulation-error (output-error) refinement of a :class:`~.feedback_nonlinearity.FeedbackNonlinearModel`.

The feedback model is identified by one least-squares solve on the *equation error* (its features taken from the
measured output).  In simulation the features come from the model's own output, and a lightly damped loop amplifies
the small equation errors (the FSM: about twice the error).  This module minimises the simulation error itself —
what the published NL-LFR baseline is trained on — over every output coefficient, linear (the input banks) and
nonlinear (the feature banks) jointly::

    L(θ, poles) = ½ Σ_records Σ_channels Σ_k e²[k] / (std(y_channel)² · T),     e = simulated − measured output

(the benchmark's metric, squared: each record and channel relative to its own spread, so every amplitude level
counts alike), from the equation-error model as the start, over the output coefficients *and* the modes (the
continuous poles every bank shares; ``refine_poles``) and, optionally, the directions of the nonlinear channels
(``channel_map``; ``refine_channels``).  The gradient is exact and costs about two simulations: a
reverse-mode (adjoint) sweep through the loop, compiled with numba (``_forward`` / ``_adjoint``), so a quasi-Newton
method (L-BFGS) can use it over ~10³ parameters where a finite-difference Jacobian would need one simulation per
parameter.  Output coefficients are scaled by the norms of their regressors (a Jacobi preconditioner of the linear
part), poles by the norm of the output's sensitivity to them (one finite difference each, at the start).

Stability at rest is enforced by a penalty on the loop linearised at rest
(:meth:`~.feedback_nonlinearity.FeedbackNonlinearModel.small_signal_poles`): every pole magnitude above
``max_radius`` costs ``stability_weight·(|λ| − max_radius)²``, with its gradient in the output coefficients
(first-order eigenvalue perturbation; the poles' share of it is left to the line search, which sees the penalty's
value).  Without it a model trained at large drive only can be unstable at small drive, where the nonlinear terms no
longer hold the loop (the FSM trained on 200 + 300 mV: a pole of magnitude 1.11). A start that already diverges
on its training records is refused; :func:`linear_part` (the feature coefficients zeroed) is a stable one on the
same modes; for a fit with nonlinear channels that diverges, :func:`refine_with_channels` starts instead from the
refined elementwise model widened by the channels. A trial point whose simulation diverges is answered with a finite wall around the last finite point
(its gradient pointing back), so the line search shortens its step instead of stopping as converged.

How many iterations: the caller's choice, made on data the fit does not see (``validation``: the iterate with the
smallest validation loss among the stable ones is returned), never on a test set.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg
import scipy.optimize

from .._jit import njit
from .feedback_nonlinearity import FEATURES, FeedbackNonlinearModel, _modal_bank, _n_states, add_channels

__all__ = ["ChannelRefinementResult", "OutputErrorResult", "linear_part", "refine_output_error",
           "refine_with_channels", "simulation_loss"]


@njit
def _forward(u: np.ndarray, c: np.ndarray, lam: np.ndarray, beta: np.ndarray, zs: np.ndarray, vs: np.ndarray,
             codes: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The loop of :meth:`FeedbackNonlinearModel.simulate` with every bank in it: outputs ``y [R, T, p]`` and fed-back
    features ``w [R, T, nf]`` of inputs ``u [R, T, m]`` (``c [m + nf, modes, p]`` complex output coefficients of the
    input banks then the feature banks; feature ``codes`` index ``FEATURES``; the features act on the channels
    ``P [q, p]`` · (y / zs), ``vs [q]`` their one-sample changes' scales)."""
    R, T, m = u.shape
    ns, nm, p = c.shape[0], c.shape[1], c.shape[2]
    nq = P.shape[0]
    nf = ns - m
    y = np.empty((R, T, p))
    w = np.empty((R, T, nf))
    yt = np.empty(p)
    for r in range(R):
        x = np.zeros((ns, nm), np.complex128)
        zp = np.zeros(nq)
        for k in range(T):
            for o in range(p):
                acc = 0.0
                for s in range(ns):
                    for j in range(nm):
                        acc += (c[s, j, o] * x[s, j]).real
                y[r, k, o] = acc
            for o in range(p):
                yt[o] = y[r, k, o] / zs[o]
            for o in range(nq):
                z = 0.0
                for i in range(p):
                    z += P[o, i] * yt[i]
                v = (z - zp[o]) / vs[o]
                zp[o] = z
                for f in range(codes.shape[0]):
                    cd = codes[f]
                    if cd == 0:
                        val = z
                    elif cd == 1:
                        val = z * abs(z)
                    elif cd == 2:
                        val = z * z * z
                    elif cd == 3:
                        val = v * abs(v)
                    else:
                        val = abs(z) * v
                    w[r, k, f * nq + o] = val
            for s in range(ns):
                sv = u[r, k, s] if s < m else w[r, k, s - m]
                for j in range(nm):
                    x[s, j] = lam[j] * x[s, j] + beta[j] * sv
    return y, w


@njit
def _adjoint(gdirect: np.ndarray, y: np.ndarray, sig: np.ndarray, c: np.ndarray, lam: np.ndarray,
             beta: np.ndarray, zs: np.ndarray, vs: np.ndarray, codes: np.ndarray, m: int, P: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Gradients of a loss whose direct gradient on the outputs is ``gdirect [R, T, p]``: ``dL/dc [m + nf, modes,
    p]``, ``dL/dλ`` and ``dL/dβ`` ``[modes]`` (complex: ``∂/∂Re + i·∂/∂Im``); ``sig [R, T, m + nf]`` = inputs then
    fed-back features of the forward pass.  Reverse sweep: ``a_x[k] = conj(λ)·a_x[k+1] + conj(c)·g_y[k]``,
    ``g_w[k] = Re(conj(β)·a_x[k+1])`` through the features' slopes into ``g_y``.  The sums over the states
    (``Σ_k g_y[k]·conj(x[k])`` for ``c``, ``Σ_k a_x[k+1]·conj(x[k])`` for ``λ``) by backward filters, so the states
    need not be stored: ``H[i] = g_y[i+1] + conj(λ)·H[i+1]``, ``G[i] = a_x[i+2] + conj(λ)·G[i+1]``, and
    ``Σ_k q[k]·conj(x[k]) = Σ_i conj(β)·s[i]·Q[i]``.  Channels ``P [q, p]`` as in :func:`_forward`; also returns
    ``dL/dP``."""
    R, T, p = y.shape
    ns, nm = c.shape[0], c.shape[1]
    nq = P.shape[0]
    dc = np.zeros((ns, nm, p), np.complex128)
    dP = np.zeros((nq, p))
    glam = np.zeros(nm, np.complex128)
    gbeta = np.zeros(nm, np.complex128)
    for r in range(R):
        ax = np.zeros((ns, nm), np.complex128)       # dL/dx[k+1]
        axn = np.zeros((ns, nm), np.complex128)      # dL/dx[k+2]
        G = np.zeros((ns, nm), np.complex128)
        H = np.zeros((nm, p), np.complex128)
        carry = np.zeros(nq)
        gy_next = np.zeros(p)
        for k in range(T - 1, -1, -1):
            for j in range(nm):
                lc = np.conj(lam[j])
                for o in range(p):
                    H[j, o] = gy_next[o] + lc * H[j, o]
                for s in range(ns):
                    G[s, j] = axn[s, j] + lc * G[s, j]
            for s in range(ns):
                sv = sig[r, k, s]
                if sv != 0.0:
                    for j in range(nm):
                        bs = np.conj(beta[j]) * sv
                        for o in range(p):
                            dc[s, j, o] += bs * H[j, o]
                        glam[j] += bs * G[s, j]
                        gbeta[j] += ax[s, j] * sv
            gz = np.zeros(nq)
            gv = np.zeros(nq)
            for f in range(codes.shape[0]):
                cd = codes[f]
                for o in range(nq):
                    s = m + f * nq + o
                    gw = 0.0
                    for j in range(nm):
                        gw += (np.conj(beta[j]) * ax[s, j]).real
                    z = 0.0
                    zprev = 0.0
                    for i in range(p):
                        z += P[o, i] * y[r, k, i] / zs[i]
                        if k > 0:
                            zprev += P[o, i] * y[r, k - 1, i] / zs[i]
                    v = (z - zprev) / vs[o]
                    if cd == 0:
                        gz[o] += gw
                    elif cd == 1:
                        gz[o] += gw * 2.0 * abs(z)
                    elif cd == 2:
                        gz[o] += gw * 3.0 * z * z
                    elif cd == 3:
                        gv[o] += gw * 2.0 * abs(v)
                    else:
                        gz[o] += gw * np.sign(z) * v
                        gv[o] += gw * abs(z)
            gy = np.empty(p)
            for i in range(p):
                gy[i] = gdirect[r, k, i]
            for o in range(nq):
                gch = gz[o] + gv[o] / vs[o] + carry[o]       # dL/d(channel o at k), through v[k] and v[k+1] too
                carry[o] = -gv[o] / vs[o]
                for i in range(p):
                    gy[i] += P[o, i] * gch / zs[i]
                    dP[o, i] += gch * y[r, k, i] / zs[i]
            for s in range(ns):
                for j in range(nm):
                    axn[s, j] = ax[s, j]
                    acc = np.conj(lam[j]) * ax[s, j]
                    for o in range(p):
                        acc += gy[o] * np.conj(c[s, j, o])
                    ax[s, j] = acc
            gy_next = gy
    return dc, glam, gbeta, dP


def _complex_coefficients(model: FeedbackNonlinearModel, theta: np.ndarray) -> np.ndarray:
    """``[signals, modes, p]`` complex output coefficients of every bank (inputs, then features)."""
    ns = _n_states(model.poles)
    n_sig = theta.shape[0] // ns
    return np.array([replace(model, theta=theta)._complex_output(theta[s * ns:(s + 1) * ns]) for s in range(n_sig)])


def _theta_gradient(model: FeedbackNonlinearModel, dc: np.ndarray) -> np.ndarray:
    """``dL/dθ`` from ``dL/dc`` (real pole: ``c = θ``; a pair's columns ``2 Re``, ``−2 Im``: ``c = 2(θa + iθb)``)."""
    rows = []
    for s in range(dc.shape[0]):
        for j, pl in enumerate(model.poles):
            if pl.imag == 0:
                rows.append(dc[s, j].real)
            else:
                rows += [2 * dc[s, j].real, 2 * dc[s, j].imag]
    return np.array(rows)


def _pole_vector(values: np.ndarray, poles: np.ndarray | None = None) -> np.ndarray:
    """Real parameters of ``values`` laid out as the poles ``poles`` (default ``values``): the real part of a real
    pole's entry, real and imaginary part of a pair's."""
    ref = values if poles is None else poles
    out: list[float] = []
    for v, pl in zip(values, ref):
        out += [float(v.real)] if pl.imag == 0 else [float(v.real), float(v.imag)]
    return np.array(out)


def _poles_from_vector(vec: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_pole_vector` for poles laid out as ``like``."""
    out, i = [], 0
    for pl in like:
        if pl.imag == 0:
            out.append(complex(vec[i]))
            i += 1
        else:
            out.append(complex(vec[i], vec[i + 1]))
            i += 2
    return np.array(out)


class _Problem:
    """Records (inputs in the model's coordinates with their warm-up, outputs measured) and their weights."""

    def __init__(self, model: FeedbackNonlinearModel, u_records: Sequence[np.ndarray], y_records: Sequence[np.ndarray],
                 warmup: int) -> None:
        self.model = model
        us = [np.asarray(u, float) for u in u_records]
        ys = [np.asarray(y, float) for y in y_records]
        if not us or len(us) != len(ys) or len({len(u) for u in us}) != 1 or any(len(u) != len(y) for u, y in
                                                                                  zip(us, ys)):
            raise ValueError("output-error refinement: expected input and output records of one length, as many")
        if warmup:
            us = [np.concatenate([u[-warmup:], u]) for u in us]
        self.warmup = warmup
        self.y_meas = np.stack(ys)                                     # original coordinates [R, T, p]
        self.M = np.eye(model.n_outputs) if model.output_map is None else np.asarray(model.output_map, float)
        self.u = np.stack(us)                                          # [R, T+warmup, m]
        T = self.y_meas.shape[1]
        self.weight = 1.0 / (np.std(self.y_meas, axis=1) ** 2 * T)     # [R, p]
        self.codes = np.array([FEATURES.index(f) for f in model.features], np.int64)
        self.ns = _n_states(model.poles)

    def _model(self, poles: np.ndarray | None, channel_map: np.ndarray | None) -> FeedbackNonlinearModel:
        mdl = self.model if poles is None else replace(self.model, poles=poles)
        return mdl if channel_map is None else replace(mdl, channel_map=channel_map)

    def evaluate(self, theta: np.ndarray, gradient: bool = True, poles: np.ndarray | None = None,
                 channel_map: np.ndarray | None = None) -> tuple[float, np.ndarray | None]:
        """Loss ``L(θ, poles, channel_map)`` and (optionally) its gradient: ``dL/dθ`` flattened, then ``dL/dpoles``
        (real part of each real pole; real and imaginary part of one of each pair), then ``dL/dchannel_map``
        flattened."""
        mdl = self._model(poles, channel_map)
        P = np.ascontiguousarray(mdl.channel_matrix())
        lam = np.exp(mdl.poles * mdl.dt)
        beta = (lam - 1.0) / mdl.poles
        c = np.ascontiguousarray(_complex_coefficients(mdl, theta))
        with np.errstate(all="ignore"):
            y, w = _forward(self.u, c, lam, beta, mdl.z_scale, mdl.v_scale, self.codes, P)
            e = y[:, self.warmup:] @ self.M.T - self.y_meas
            loss = 0.5 * float(np.sum(self.weight[:, None, :] * e ** 2))
        n_pole = len(_pole_vector(mdl.poles))
        if not np.isfinite(loss):
            return float("inf"), (np.zeros(theta.size + n_pole + P.size) if gradient else None)
        if not gradient:
            return loss, None
        gd = np.zeros_like(y)
        gd[:, self.warmup:] = (self.weight[:, None, :] * e) @ self.M
        sig = np.ascontiguousarray(np.concatenate([self.u, w], axis=2))
        dc, glam, gbeta, dP = _adjoint(gd, y, sig, c, lam, beta, mdl.z_scale, mdl.v_scale, self.codes,
                                       mdl.n_inputs, P)
        pl, dt = mdl.poles, mdl.dt
        g_p = np.conj(dt * lam) * glam + np.conj((dt * lam * pl - (lam - 1.0)) / pl ** 2) * gbeta
        return loss, np.concatenate([_theta_gradient(mdl, dc).ravel(), _pole_vector(g_p, pl), dP.ravel()])

    def outputs(self, theta: np.ndarray, poles: np.ndarray | None = None, channel_map: np.ndarray | None = None
                ) -> np.ndarray:
        """Simulated outputs ``[R, T, p]`` in the model's coordinates (warm-up included)."""
        mdl = self._model(poles, channel_map)
        lam = np.exp(mdl.poles * mdl.dt)
        with np.errstate(all="ignore"):
            y, _ = _forward(self.u, np.ascontiguousarray(_complex_coefficients(mdl, theta)), lam,
                            (lam - 1.0) / mdl.poles, mdl.z_scale, mdl.v_scale, self.codes,
                            np.ascontiguousarray(mdl.channel_matrix()))
        return y

    def column_norms(self) -> np.ndarray:
        """Norms of every coefficient's regressor (inputs: the input banks; features: the banks of the features of
        the measured output, as in the equation-error fit), for scaling."""
        mdl, ns = self.model, self.ns
        y = self.y_meas @ np.linalg.inv(self.M).T
        if self.warmup:
            y = np.concatenate([y[:, -self.warmup:], y], axis=1)
        z = (y / mdl.z_scale) @ mdl.channel_matrix().T
        v = np.diff(z, axis=1, prepend=z[:, :1]) / mdl.v_scale
        from .feedback_nonlinearity import _features

        sq = np.zeros(mdl.theta.shape[0])
        for r in range(len(z)):
            sig = np.hstack([self.u[r], _features(z[r], v[r], mdl.features)])
            sq += np.sum(_modal_bank(mdl.poles, mdl.dt, sig) ** 2, axis=0)
        n = np.sqrt(sq)
        n[n == 0] = 1.0
        return n


def _stability_penalty(model: FeedbackNonlinearModel, theta: np.ndarray, max_radius: float, weight: float
                       ) -> tuple[float, np.ndarray]:
    """``weight·Σ max(0, |λ| − max_radius)²`` over the poles of the loop linearised at rest, and its gradient in θ
    (``dλ = uᴴ·B·dK·v / uᴴv`` with ``K = C_lin/z_scale``, first-order eigenvalue perturbation)."""
    grad = np.zeros_like(theta)
    if "lin" not in model.features or weight <= 0:
        return 0.0, grad
    mdl = replace(model, theta=theta)
    A, B, C = mdl.small_signal_matrices()
    Pc = mdl.channel_matrix()
    K = Pc @ (C / mdl.z_scale[:, None])
    lam, VL, VR = scipy.linalg.eig(A + B @ K, left=True, right=True)
    over = np.abs(lam) - max_radius
    pen = float(weight * np.sum(np.maximum(over, 0.0) ** 2))
    if pen == 0.0:
        return 0.0, grad
    dK = np.zeros_like(K)
    for e in np.nonzero(over > 0)[0]:
        u, v = VL[:, e], VR[:, e]
        dl_dK = np.outer(np.conj(u) @ B, v) / (np.conj(u) @ v)        # dλ/dK[o, n]
        d_abs = np.real(np.conj(lam[e]) / abs(lam[e]) * dl_dK)
        dK += weight * 2 * over[e] * d_abs
    dC = (Pc.T @ dK) / mdl.z_scale[:, None]                          # [p, n]
    # C's columns from θ of the lin banks: per signal s (channel fed back), per mode: real → θ row;
    # pair → columns 2θa, −2θb (small_signal_matrices' layout)
    ns, m, nq = _n_states(mdl.poles), mdl.n_inputs, mdl.n_channels
    k0 = m + mdl.features.index("lin") * nq
    col = 0
    for s in range(nq):
        i = 0
        for pl in mdl.poles:
            row = (k0 + s) * ns + i
            if pl.imag == 0:
                grad[row] += dC[:, col]
                col += 1
                i += 1
            else:
                grad[row] += 2 * dC[:, col]
                grad[row + 1] += -2 * dC[:, col + 1]
                col += 2
                i += 2
    return pen, grad


@dataclass(frozen=True)
class OutputErrorResult:
    """A refined model and the course of the refinement.

    Attributes
    ----------
    model : FeedbackNonlinearModel
        The returned iterate: among those stable at rest (pole magnitudes < 1), the one with the smallest validation
        loss (training loss without validation records) plus stability penalty.
    iteration : int
        Its iteration number (0 = the start).
    history : list of dict
        Per scored iteration: ``loss`` (training), ``validation`` (if given), ``radius`` (largest pole magnitude at
        rest), ``penalty`` (the stability penalty).
    """

    model: FeedbackNonlinearModel
    iteration: int
    history: list[dict[str, float]] = field(default_factory=list)


def linear_part(model: FeedbackNonlinearModel) -> FeedbackNonlinearModel:
    """``model`` with its fed-back feature coefficients set to zero: the input banks alone on the same (stable)
    modes, so it cannot diverge — a start for the refinement when the equation-error fit diverges in simulation.

    Parameters
    ----------
    model : FeedbackNonlinearModel
        The model.

    Returns
    -------
    FeedbackNonlinearModel
        The same modes, scales and input coefficients; every feature coefficient zero.
    """
    theta = np.array(model.theta, float)
    theta[model.n_inputs * _n_states(model.poles):] = 0.0
    return replace(model, theta=theta)


def simulation_loss(model: FeedbackNonlinearModel, u_records: Sequence[np.ndarray], y_records: Sequence[np.ndarray],
                    warmup: int = 0) -> float:
    """The loss the refinement minimises (module docstring), of ``model`` on the given records.

    Parameters
    ----------
    model : FeedbackNonlinearModel
        The model.
    u_records, y_records : sequences of ndarray
        Input ``[T, m]`` and measured output ``[T, p]`` records of one length.
    warmup : int
        Samples of each record's end simulated first (its period, for periodic records).

    Returns
    -------
    float
        ``inf`` when the simulation diverges.
    """
    return _Problem(model, u_records, y_records, warmup).evaluate(model.theta, gradient=False)[0]


def refine_output_error(model: FeedbackNonlinearModel, u_records: Sequence[np.ndarray],
                        y_records: Sequence[np.ndarray], warmup: int = 0, max_iterations: int = 100,
                        validation: tuple[Sequence[np.ndarray], Sequence[np.ndarray]] | None = None,
                        max_radius: float = 0.9995, stability_weight: float = 1e3, every: int = 5,
                        refine_poles: bool = True, refine_channels: bool = False, memory: int = 20,
                        progress: Callable[[str], None] | None = None) -> OutputErrorResult:
    """Minimise the simulation error of ``model`` over all its output coefficients (module docstring).

    Parameters
    ----------
    model : FeedbackNonlinearModel
        The start (e.g. the equation-error fit of ``identify_feedback_nonlinearity``).
    u_records, y_records : sequences of ndarray
        Training input ``[T, m]`` and measured output ``[T, p]`` records of one length.
    warmup : int
        Samples of each record's end simulated first and not scored (the period, for periodic records).
    max_iterations : int
        L-BFGS iterations at most.
    validation : (u_records, y_records), optional
        Records not fitted on (same length as each other): scored every ``every`` iterations; the best stable
        iterate on them is returned.
    max_radius : float
        Pole magnitude at rest above which the stability penalty acts (< 1).
    stability_weight : float
        Weight of that penalty (0 = none).
    every : int
        Iterations between validation scores.
    refine_poles : bool
        Refine the modes (the continuous poles shared by every bank) too, each scaled by the output's sensitivity
        to it; False = the start's modes kept.
    refine_channels : bool
        Refine the directions of the nonlinear channels too (``channel_map``, the identity when the model has none:
        see ``feedback_nonlinearity.add_channels``), each entry scaled by the output's sensitivity to it.
    memory : int
        Correction pairs L-BFGS keeps (its approximation of the curvature: more pairs, a better one on a badly
        conditioned loss, for little more than the gradient's cost).
    progress : callable, optional
        Progress lines.

    Returns
    -------
    OutputErrorResult

    Raises
    ------
    ValueError
        Mismatched records, or a diverging start.
    """
    say = progress or (lambda s: None)
    prob = _Problem(model, u_records, y_records, warmup)
    val = _Problem(model, *validation, warmup) if validation is not None else None
    scale = prob.column_norms()
    theta0 = np.asarray(model.theta, float)
    shape = theta0.shape
    pv0 = _pole_vector(model.poles)
    l0 = prob.evaluate(theta0, gradient=False)[0]
    if not np.isfinite(l0):
        raise ValueError("output-error refinement: the start diverges in simulation on the training records")
    if refine_poles:
        # each pole parameter scaled by the norm of the output's sensitivity to it (a finite difference), as the
        # output coefficients are by their regressors' norms
        y0 = prob.outputs(theta0)
        pscale = np.empty(len(pv0))
        for i in range(len(pv0)):
            h = 1e-7 * float(np.max(np.abs(model.poles)))
            pv = pv0.copy()
            pv[i] += h
            pscale[i] = max(float(np.linalg.norm(prob.outputs(theta0, _poles_from_vector(pv, model.poles)) - y0)) / h,
                            1e-30)
    else:
        pscale = np.ones(0)
    P0 = model.channel_matrix()
    if refine_channels:
        # each entry scaled by the norm of the output's sensitivity to it (a finite difference); an entry the output
        # does not yet depend on (a new channel whose coefficients are zero) keeps the scale of the largest one
        y0 = prob.outputs(theta0)
        cscale = np.empty(P0.size)
        for i in range(P0.size):
            h = 1e-6
            Pp = P0.ravel().copy()
            Pp[i] += h
            cscale[i] = float(np.linalg.norm(prob.outputs(theta0, None, Pp.reshape(P0.shape)) - y0)) / h
        cscale[cscale <= 1e-12 * max(float(cscale.max()), 1e-300)] = max(float(cscale.max()), 1.0)
    else:
        cscale = np.ones(0)
    n_pole = len(pscale)

    def unpack(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        theta = phi[:theta0.size].reshape(shape) / scale[:, None]
        poles = model.poles if not refine_poles else _poles_from_vector(
            pv0 + phi[theta0.size:theta0.size + n_pole] / pscale, model.poles)
        P = None if not refine_channels else P0 + (phi[theta0.size + n_pole:] / cscale).reshape(P0.shape)
        return theta, poles, P

    last: list[tuple[np.ndarray, float, np.ndarray]] = []    # the last finite point: (phi, value, gradient)

    def stand_in(phi: np.ndarray) -> tuple[float, np.ndarray]:
        # A diverging trial point has no loss to give. A constant with a zero gradient ends L-BFGS-B's line search
        # at the start as if converged; instead: the last finite value plus a large quadratic wall around the last
        # finite point (its gradient points back to it), so the line search shortens the step and goes on.
        p_f, f_f, g_f = last[-1]
        d = phi - p_f
        dd = max(float(d @ d), 1e-300)
        w = (10.0 * abs(f_f) + float(np.abs(g_f @ d)) + 1.0) / dd
        return f_f + w * dd, g_f + 2.0 * w * d

    def fun(phi: np.ndarray) -> tuple[float, np.ndarray]:
        theta, poles, P = unpack(phi)
        if refine_poles and np.any(poles.real >= 0):
            return stand_in(phi)
        loss, g = prob.evaluate(theta, poles=poles, channel_map=P)
        if not np.isfinite(loss):
            return stand_in(phi)
        mdl = replace(model, poles=poles) if P is None else replace(model, poles=poles, channel_map=P)
        pen, gp = _stability_penalty(mdl, theta, max_radius, stability_weight)
        assert g is not None
        g_theta = (g[:theta0.size].reshape(shape) + gp) / scale[:, None]
        parts = [g_theta.ravel()]
        if refine_poles:
            parts.append(g[theta0.size:theta0.size + n_pole] / pscale)
        if refine_channels:
            parts.append(g[theta0.size + n_pole:] / cscale)
        out = loss + pen, np.concatenate(parts)
        last[:] = [(phi.copy(), out[0], out[1].copy())]
        return out

    history: list[dict[str, float]] = []
    best: tuple[float, int, FeedbackNonlinearModel] | None = None

    def record(it: int, phi: np.ndarray) -> None:
        nonlocal best
        theta, poles, P = unpack(phi)
        mdl = replace(model, theta=theta, poles=poles)
        if P is not None:
            mdl = replace(mdl, channel_map=P)
        row = {"iteration": float(it), "loss": prob.evaluate(theta, False, poles, P)[0],
               "radius": float(np.max(np.abs(mdl.small_signal_poles()))),
               "penalty": _stability_penalty(mdl, theta, max_radius, stability_weight)[0]}
        score = row["loss"]
        if val is not None:
            row["validation"] = val.evaluate(theta, False, poles, P)[0]
            score = row["validation"]
        score += row["penalty"]             # the bound counts in the choice too (a soft one: slightly crossed)
        history.append(row)
        say("output error: " + ", ".join(f"{k} {v:.5g}" for k, v in row.items()))
        if row["radius"] < 1.0 and np.isfinite(score) and (best is None or score < best[0]):
            best = (score, it, mdl)

    phi0 = np.concatenate([(theta0 * scale[:, None]).ravel(), np.zeros(len(pscale)), np.zeros(len(cscale))])
    record(0, phi0)
    count = [0]

    def callback(xk: np.ndarray) -> None:
        count[0] += 1
        if count[0] % every == 0 or count[0] == max_iterations:
            record(count[0], xk)

    res = scipy.optimize.minimize(fun, phi0, jac=True, method="L-BFGS-B", callback=callback,
                                  options={"maxiter": max_iterations, "maxcor": memory})
    if count[0] % every:                                       # stopped between two scores: score the last
        record(count[0], res.x)
    if best is None:
        return OutputErrorResult(model=model, iteration=0, history=history)
    return OutputErrorResult(model=best[2], iteration=best[1], history=history)


@dataclass(frozen=True)
class ChannelRefinementResult:
    """A model with nonlinear channels refined on the simulation error, and which way it was reached.

    Attributes
    ----------
    model : FeedbackNonlinearModel
        The refined model (its channels' directions refined too).
    iteration : int
        The kept iterate of the last refinement (0 = its start).
    history : list of dict
        The last refinement's course (``OutputErrorResult.history``).
    route : str
        ``'from_start'``: the channels-from-the-start fit refined directly; ``'widened'``: that fit diverged in
        simulation on its own training records, so the elementwise model was refined, widened by the channels
        (zero coefficients) and refined again.
    elementwise : OutputErrorResult or None
        On the ``'widened'`` route, the elementwise refinement (its model is the widened one's start).
    """

    model: FeedbackNonlinearModel
    iteration: int
    history: list[dict[str, float]]
    route: str
    elementwise: OutputErrorResult | None = None


def refine_with_channels(start: FeedbackNonlinearModel,
                         elementwise_start: FeedbackNonlinearModel | Callable[[], FeedbackNonlinearModel],
                         directions: np.ndarray, u_records: Sequence[np.ndarray], y_records: Sequence[np.ndarray],
                         warmup: int = 0, max_iterations: int = 100, elementwise_iterations: int | None = None,
                         validation: tuple[Sequence[np.ndarray], Sequence[np.ndarray]] | None = None,
                         **options: Any) -> ChannelRefinementResult:
    """Refine an equation-error fit that has nonlinear channels, with a stable way round a start that diverges.

    The fit with the channels in it from the start (``identify_feedback_nonlinearity(..., channels=...)``) is the
    better start when it simulates (it is not confined to the elementwise model's basin).  When it diverges on its
    own training records — a fit on large drive only, whose loop at rest the nonlinear terms no longer hold — its
    linear part is a poor start: every feature coefficient, the channels' included, must then be found by descent
    from zero.  The refined *elementwise* model widened by the channels (``add_channels``: the same model, so its
    refinement starts where the elementwise one ended) keeps what the elementwise refinement found.  So: ``start``
    refined with its channels if it simulates finitely on the training records; otherwise ``elementwise_start`` (its
    linear part if it diverges too) refined, widened by ``directions``, and refined with the channels.

    Parameters
    ----------
    start : FeedbackNonlinearModel
        The equation-error fit with the channels included.
    elementwise_start : FeedbackNonlinearModel or callable
        The equation-error fit of the same data without the added channels (same modes and coordinates), or a
        function without arguments that returns it (called only on the widened route: the fit is then not made
        when ``start`` simulates).
    directions : ndarray
        ``[k, p]``: the channels ``start`` adds, as combinations of the model outputs (``add_channels``).
    u_records, y_records : sequences of ndarray
        Training records (``refine_output_error``).
    warmup : int
        As in ``refine_output_error``.
    max_iterations : int
        Iterations of the refinement with the channels.
    elementwise_iterations : int, optional
        Iterations of the elementwise refinement on the widened route (default ``max_iterations``).
    validation : (u_records, y_records), optional
        Records that choose the kept iterate of each refinement (``refine_output_error``).
    **options
        Passed to every ``refine_output_error`` call (``max_radius``, ``stability_weight``, ``every``, ...).

    Returns
    -------
    ChannelRefinementResult
    """
    if np.isfinite(simulation_loss(start, u_records, y_records, warmup)):
        res = refine_output_error(start, u_records, y_records, warmup, max_iterations, validation,
                                  refine_channels=True, **options)
        return ChannelRefinementResult(res.model, res.iteration, res.history, "from_start")
    elem = elementwise_start() if callable(elementwise_start) else elementwise_start
    if not np.isfinite(simulation_loss(elem, u_records, y_records, warmup)):
        elem = linear_part(elem)
    n_elem = max_iterations if elementwise_iterations is None else elementwise_iterations
    res_elem = refine_output_error(elem, u_records, y_records, warmup, n_elem, validation, **options)
    wide = add_channels(res_elem.model, directions, y_records)
    res = refine_output_error(wide, u_records, y_records, warmup, max_iterations, validation, refine_channels=True,
                              **options)
    return ChannelRefinementResult(res.model, res.iteration, res.history, "widened", res_elem)
