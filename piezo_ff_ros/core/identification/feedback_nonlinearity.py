"""A linear MIMO model with a static nonlinearity of its output fed back into it (an NL-LFR-like structure).

For multisine records of a weakly nonlinear system measured at several amplitude levels — the CubeSpec fine
steering mirror, whose resonances soften and lose gain as the drive grows (piezo hysteresis in the suspension) —
one linear model cannot serve every level: its error grows with the amplitude.  This module identifies one model
for all levels::

    x_s[k+1] = Λ x_s[k] + β s[k]            one bank of modal states per signal s (inputs u_j and features w_l)
    y[k]     = Σ_s C_s x_s[k]               (strictly proper: no direct term, so the loop below is causal)
    w[k]     = f(y[k], y[k] − y[k−1])       static features of the model's own output, fed back as signals

with ``Λ``, ``β`` the exact-ZOH modes of a best linear approximation of all the training records (``bla``:
nonparametric FRF pooled over realizations and levels, frequency-domain subspace poles) and ``f`` a fixed set of
elementwise functions of each output channel (``FEATURES``): ``lin`` (a linear loop: lets the fit move the poles
away from the pooled ones), ``abs2`` = z·|z| and ``cube`` = z³ (a static stiffness nonlinearity: an effective
feedback gain growing with the amplitude, i.e. resonances that shift with level), ``vabs2`` = v·|v| and ``yv`` =
|z|·v (damping that grows with the amplitude — what a hysteresis loop's area does), with z the output and v its
one-sample change, both over their training RMS.  Optionally the features act on the *actuator coordinates*
``G(0)⁻¹·y`` instead (the output mapped back through the static gain: the strain of each actuator, where a piezo
stack's stiffness nonlinearity lives); the model still reports outputs.  And optionally on more *channels* than
outputs (``channel_map``): each channel a combination of all the model's outputs (e.g. the actuator coordinates and
the outputs themselves at once, or the difference of two outputs — a spring between them), every feature applied to
every channel: several nonlinear branches, so that products across outputs (``(y₁ − y₂)³``) are within reach where
the elementwise basis only has ``y₁³`` and ``y₂³``.  ``add_channels`` widens an identified model by such channels
with zero coefficients (the same model, a start that cannot do worse); the directions are then learnt with
everything else by the simulation-error refinement.

Identification is one linear least-squares problem (equation error): the features are evaluated on the *measured*
output, filtered through the modal banks, and every ``C_s`` is solved for at once, each record weighted by the
inverse RMS of its output (so that every amplitude level counts in relative terms, as the benchmark's metric
does).  The model is then used in *pure simulation*: ``w`` is computed from the model's own output, never from a
measurement (:meth:`FeedbackNonlinearModel.simulate`).  Periodic records are simulated from the periodic steady
state (the last period prepended as warm-up, the way the published baselines suppress the transient).

Why this structure: it is the nonlinear LFR of Schoukens & Tiels (and of the data set's published NL-LFR baseline,
which puts a neural network in the feedback path) restricted to a static basis on the output, so that it is
identified without iterative optimisation (no local minima, about a minute for the 18 training realizations of
the FSM) and simulated by one recursion over the samples (vectorised over records).  What it is not: it is
fitted on the equation error, not on the simulation error — its simulation error is larger than its equation
error (a lightly damped loop amplifies small model errors); ``output_error.refine_output_error`` refines it on the
simulation error, as the published NL-LFR is trained (docs/diagnosis.md, real data).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.signal

from . import bla

__all__ = ["FEATURES", "FeedbackNonlinearModel", "identify_feedback_nonlinearity", "benchmark_nrmse_percent",
           "periodic_records", "add_channels"]

#: the static functions of each output channel the feedback may use (module docstring)
FEATURES = ("lin", "abs2", "cube", "vabs2", "yv")


def _features(z: np.ndarray, v: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """Features ``[..., len(names)·p]`` of the scaled output ``z`` and its scaled one-sample change ``v``
    (``[..., p]``), grouped by feature."""
    out = []
    for name in names:
        if name == "lin":
            out.append(z)
        elif name == "abs2":
            out.append(z * np.abs(z))
        elif name == "cube":
            out.append(z ** 3)
        elif name == "vabs2":
            out.append(v * np.abs(v))
        elif name == "yv":
            out.append(np.abs(z) * v)
        else:
            raise ValueError(f"feature {name!r}: expected one of {', '.join(FEATURES)}")
    return np.concatenate(out, axis=-1) if out else np.zeros(z.shape[:-1] + (0,))


def _modal_bank(poles: np.ndarray, dt: float, s: np.ndarray) -> np.ndarray:
    """Real basis signals ``[T, n_signals·n_states]`` of the exact-ZOH modes ``poles`` (one per pair) driven by
    each column of ``s [T, n_signals]``: ``β/(q − λ)`` per real pole; for a pair, 2·Re and −2·Im of the complex
    one (the column convention of ``bla._basis``, so FRF-fitted coefficients apply unchanged).  Columns grouped by
    signal."""
    s = np.asarray(s, float)
    T, n_sig = s.shape
    per_signal: list[list[np.ndarray]] = [[] for _ in range(n_sig)]
    for pl in poles:
        lam = np.exp(pl * dt)
        beta = (lam - 1.0) / pl
        if pl.imag == 0:
            v = scipy.signal.lfilter([0.0, beta.real], [1.0, -lam.real], s, axis=0)
            for j in range(n_sig):
                per_signal[j].append(v[:, j:j + 1])
        else:
            v = scipy.signal.lfilter([0.0, beta], [1.0, -lam], s.astype(complex), axis=0)
            for j in range(n_sig):
                per_signal[j].append(np.column_stack([2 * v[:, j].real, -2 * v[:, j].imag]))
    return np.hstack([np.hstack(cols) for cols in per_signal])


def _n_states(poles: np.ndarray) -> int:
    return int(sum(1 if pl.imag == 0 else 2 for pl in poles))


@dataclass(frozen=True)
class FeedbackNonlinearModel:
    """An identified model (module docstring): modes, feature set, scales and output coefficients.

    Attributes
    ----------
    poles : ndarray
        Continuous poles [1/s] whose exact ZOH are the modes (real ones and one of each pair).
    dt : float
        Sample period [s].
    features : tuple of str
        Feature names (``FEATURES``), each applied to every output channel.
    z_scale, v_scale : ndarray
        Per-output scales of the output and of its one-sample change (training RMS).
    theta : ndarray
        Output coefficients ``[(n_inputs + n_features·n_outputs)·n_states, n_outputs]``, grouped by signal.
    n_inputs : int
        Number of input channels.
    output_map : ndarray, optional
        ``[p, p]``: the model runs in coordinates ``y' = y·output_map⁻ᵀ`` (features on them) and reports
        ``y = y'·output_mapᵀ``; None = the outputs themselves.
    channel_map : ndarray, optional
        ``[q, p]``: the features act on ``q`` *channels* ``c = (y'/z_scale)·channel_mapᵀ`` (learnt directions
        through the model's outputs: several nonlinear branches, each a combination of all outputs) instead of
        on each output; ``v_scale`` then has ``q`` entries.  None = the identity (one channel per output).
    """

    poles: np.ndarray
    dt: float
    features: tuple[str, ...]
    z_scale: np.ndarray
    v_scale: np.ndarray
    theta: np.ndarray
    n_inputs: int
    output_map: np.ndarray | None = None
    channel_map: np.ndarray | None = None

    @property
    def n_outputs(self) -> int:
        """Number of output channels (columns of ``theta``)."""
        return int(self.theta.shape[1])

    @property
    def n_channels(self) -> int:
        """Number of nonlinear channels the features act on (rows of ``channel_map``; the outputs without one)."""
        return self.n_outputs if self.channel_map is None else int(self.channel_map.shape[0])

    def channel_matrix(self) -> np.ndarray:
        """``channel_map`` (``[q, p]``), the identity when there is none."""
        return np.eye(self.n_outputs) if self.channel_map is None else np.asarray(self.channel_map, float)

    def _complex_output(self, theta_s: np.ndarray) -> np.ndarray:
        """Complex output coefficients ``[n_modes, n_outputs]`` of one signal's bank: ``y = Re(Σ c·x)`` with the
        complex modal state ``x`` (``2·(a + i·b)`` for a pair's columns ``2 Re, −2 Im``)."""
        out, i = [], 0
        for pl in self.poles:
            if pl.imag == 0:
                out.append(theta_s[i].astype(complex))
                i += 1
            else:
                out.append(2 * (theta_s[i] + 1j * theta_s[i + 1]))
                i += 2
        return np.array(out)

    def small_signal_poles(self) -> np.ndarray:
        """Discrete poles of the model linearised at rest (amplitude → 0): the input banks' modes and the closed
        loop of the ``lin`` feature (every other feature has zero slope at 0).  A magnitude ≥ 1 means the model
        diverges once the drive is small enough for the nonlinear terms to stop holding the loop.

        Returns
        -------
        ndarray
            Complex eigenvalues of the loop's state matrix (the input banks' own modes, ``exp(p·dt)``, are stable by
            construction and not repeated).
        """
        if "lin" not in self.features:
            return np.exp(self.poles * self.dt)
        A, B, C = self.small_signal_matrices()
        return np.asarray(np.linalg.eigvals(A + B @ (self.channel_matrix() @ (C / self.z_scale[:, None]))))

    def small_signal_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A, B, C`` of the ``lin`` feature's banks (real modal form; the loop at rest is
        ``A + B·channel_map·C/z_scale``).

        Returns
        -------
        tuple of ndarray
            ``A [n, n]``, ``B [n, q]`` (one bank per fed-back channel) and ``C [p, n]``.

        Raises
        ------
        ValueError
            The model has no ``lin`` feature.
        """
        if "lin" not in self.features:
            raise ValueError("small-signal matrices: the model has no linear loop (feature 'lin')")
        ns = _n_states(self.poles)
        m, p, nq = self.n_inputs, self.n_outputs, self.n_channels
        k0 = m + self.features.index("lin") * nq         # the lin feature's first signal
        blocks_a, blocks_b, blocks_c = [], [], []
        for s in range(nq):
            theta_s = self.theta[(k0 + s) * ns:(k0 + s + 1) * ns]          # [ns, p]
            i = 0
            for pl in self.poles:
                lam = np.exp(pl * self.dt)
                beta = (lam - 1.0) / pl
                if pl.imag == 0:
                    blocks_a.append(np.array([[lam.real]]))
                    blocks_b.append((np.array([[beta.real]]), s))
                    blocks_c.append(theta_s[i:i + 1].T)
                    i += 1
                else:   # x = Re v, Im v;  y = 2a·Re v − 2b·Im v (the bank's column convention)
                    blocks_a.append(np.array([[lam.real, -lam.imag], [lam.imag, lam.real]]))
                    blocks_b.append((np.array([[beta.real], [beta.imag]]), s))
                    blocks_c.append(np.column_stack([2 * theta_s[i], -2 * theta_s[i + 1]]))
                    i += 2
        A = scipy.linalg.block_diag(*blocks_a)
        n = A.shape[0]
        B = np.zeros((n, nq))
        C = np.hstack(blocks_c)                          # [p, n]
        r = 0
        for (b, s) in blocks_b:
            B[r:r + len(b), s] = b[:, 0]
            r += len(b)
        return A, B, C

    def equation_error_output(self, u: np.ndarray, y: np.ndarray, warmup: int = 0) -> np.ndarray:
        """The model's output with the features taken from the *measured* output ``y`` (what the fit minimises;
        not a simulation): the part of the simulation error that is not the loop amplifying model errors.

        Parameters
        ----------
        u, y : ndarray
            Input ``[T, n_inputs]`` and measured output ``[T, n_outputs]`` of one record.
        warmup : int
            As in :meth:`simulate` (the end of both records prepended).

        Returns
        -------
        ndarray
            ``[T, n_outputs]``.
        """
        u, y = np.asarray(u, float), np.asarray(y, float)
        if self.output_map is not None:
            y = y @ np.linalg.inv(self.output_map).T
        if warmup:
            u, y = np.concatenate([u[-warmup:], u]), np.concatenate([y[-warmup:], y])
        z = (y / self.z_scale) @ self.channel_matrix().T
        v = np.diff(z, axis=0, prepend=z[:1]) / self.v_scale
        out: np.ndarray = _modal_bank(self.poles, self.dt, np.hstack([u, _features(z, v, self.features)])) @ self.theta
        return self._mapped(out[warmup:])

    def _mapped(self, y: np.ndarray) -> np.ndarray:
        return y if self.output_map is None else np.asarray(y @ self.output_map.T)

    def simulate(self, u_records: Sequence[np.ndarray], warmup: int = 0) -> list[np.ndarray]:
        """Pure simulation (the output is the model's own, never a measurement) of each record ``u [T, m]``.

        Parameters
        ----------
        u_records : sequence of ndarray
            Input records ``[T, n_inputs]``, all of the same length (simulated together).
        warmup : int
            Samples of each record's end prepended and simulated first (the periodic steady state of a periodic
            record: its period); not returned.

        Returns
        -------
        list of ndarray
            ``[T, n_outputs]`` per record.
        """
        ns = _n_states(self.poles)
        m, p = self.n_inputs, self.n_outputs
        nf = len(self.features) * self.n_channels
        P = self.channel_matrix()
        us = [np.asarray(u, float) for u in u_records]
        if any(u.ndim != 2 or u.shape[1] != m for u in us) or len({len(u) for u in us}) != 1:
            raise ValueError(f"simulate: expected records [T, {m}] of one length")
        if warmup:
            us = [np.concatenate([u[-warmup:], u]) for u in us]
        y_lin = np.stack([_modal_bank(self.poles, self.dt, u) @ self.theta[:m * ns] for u in us])   # [R, T, p]
        c = np.array([self._complex_output(self.theta[(m + k) * ns:(m + k + 1) * ns]) for k in range(nf)]
                     ).reshape(nf, len(self.poles), p)
        if nf == 0:                                          # a linear model: no loop to run
            return [self._mapped(o[warmup:]) for o in y_lin]
        lam = np.exp(self.poles * self.dt)
        beta = (lam - 1.0) / self.poles
        R, T = y_lin.shape[:2]
        x = np.zeros((R, nf, len(self.poles)), complex)
        out = np.empty_like(y_lin)
        z_prev = np.zeros((R, self.n_channels))
        for k in range(T):
            y = y_lin[:, k] + np.einsum("rsm,smo->ro", x, c).real
            out[:, k] = y
            z = (y / self.z_scale) @ P.T
            w = _features(z, (z - z_prev) / self.v_scale, self.features)
            z_prev = z
            x = lam * x + beta * w[:, :, None]
        return [self._mapped(o[warmup:]) for o in out]


def periodic_records(u: np.ndarray, y: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Records from arrays ``[N, channels, realizations, periods]`` (the FSM layout): one record per realization,
    its periods one after the other."""
    u, y = np.asarray(u, float), np.asarray(y, float)
    if u.ndim != 4 or y.ndim != 4 or u.shape[0] != y.shape[0] or u.shape[2:] != y.shape[2:]:
        raise ValueError(f"periodic records: expected [N, channels, realizations, periods] arrays of one layout, got "
                         f"{u.shape} and {y.shape}")
    us = [np.concatenate([u[:, :, r, k] for k in range(u.shape[3])]) for r in range(u.shape[2])]
    ys = [np.concatenate([y[:, :, r, k] for k in range(y.shape[3])]) for r in range(y.shape[2])]
    return us, ys


def identify_feedback_nonlinearity(u_records: Sequence[np.ndarray], y_records: Sequence[np.ndarray], period: int,
                                   dt: float, order: int, features: Sequence[str] = ("lin", "abs2", "cube"),
                                   coordinates: str = "outputs", channels: np.ndarray | str | None = None
                                   ) -> FeedbackNonlinearModel:
    """Identify the model of the module docstring from periodic records.

    Parameters
    ----------
    u_records, y_records : sequences of ndarray
        Input ``[T, m]`` and measured output ``[T, p]`` records, each a whole number (≥ 2) of periods of a
        periodic excitation (e.g. every realization of every amplitude level of the training set).
    period : int
        Samples per period.
    dt : float
        Sample period [s].
    order : int
        State dimension of the pooled best linear approximation whose modes the banks use.
    features : sequence of str
        Feature names (``FEATURES``); empty = a linear model refitted in the time domain.
    coordinates : {'outputs', 'actuators'}
        Where the features act: on each output, or (as many inputs as outputs) on each *actuator coordinate*
        ``G(0)⁻¹·y`` — the output mapped back through the static gain of the best linear approximation (its lowest
        five excited bins, real part), i.e. in volts of the actuator that would produce it statically: where a piezo
        stack's own stiffness nonlinearity lives.
    channels : ndarray, 'outputs' or 'outputs+differences', optional
        ``[k, p]``: more nonlinear channels, each a combination of the coordinates above (as in
        :func:`add_channels`, rescaled to unit RMS over the records), fed through every feature besides the
        coordinates themselves.  ``'outputs'`` (with ``coordinates='actuators'``): the measured outputs themselves
        (the rows of the static gain that maps the actuator coordinates back to them), so the features act in both
        coordinate systems at once — one fit, the gain computed once.  ``'outputs+differences'``: those and the
        pairwise differences of the measured outputs (the mirror's tilts between its reference points).

    Returns
    -------
    FeedbackNonlinearModel

    Raises
    ------
    ValueError
        Records that are not whole periods, of mismatched shapes, or an unknown feature.
    """
    features = tuple(features)
    if coordinates not in ("outputs", "actuators"):
        raise ValueError(f"coordinates {coordinates!r}: expected 'outputs' or 'actuators'")
    if isinstance(channels, str) and (channels not in ("outputs", "outputs+differences")
                                      or coordinates != "actuators"):
        raise ValueError(f"feedback nonlinearity: channels={channels!r} needs coordinates='actuators' (the measured "
                         "outputs as channels) or an array of directions")
    _features(np.zeros((1, 1)), np.zeros((1, 1)), features)          # names checked before any work
    if not u_records or len(u_records) != len(y_records):
        raise ValueError("feedback nonlinearity: expected as many output records as input records (≥ 1)")
    us = [np.asarray(u, float) for u in u_records]
    ys = [np.asarray(y, float) for y in y_records]
    m, p = us[0].shape[1], ys[0].shape[1]
    for u, y in zip(us, ys):
        if u.shape[0] != y.shape[0] or u.shape[0] % period or u.shape[0] < 2 * period or u.shape[1] != m \
                or y.shape[1] != p:
            raise ValueError(f"feedback nonlinearity: records of {u.shape} / {y.shape} samples are not ≥ 2 whole "
                             f"periods of {period} samples with {m} inputs and {p} outputs")
    # modes: the best linear approximation of every record's last period (pooled over realizations and levels)
    U = np.fft.rfft(np.stack([u[-period:] for u in us], axis=2), axis=0)
    Y = np.fft.rfft(np.stack([y[-period:] for y in ys], axis=2), axis=0)
    bins = np.nonzero(bla._excited(U))[0]
    poles, _ = bla._fit_order(U, Y, bins, period, int(order), dt)
    output_map = None
    if coordinates == "actuators":
        if m != p:
            raise ValueError(f"feedback nonlinearity: actuator coordinates need as many inputs as outputs ({m} vs {p})")
        output_map = np.mean([np.real(Y[k] @ np.linalg.pinv(U[k])) for k in bins[:5]], axis=0)
        to_actuators = np.linalg.inv(output_map)
        ys = [y @ to_actuators.T for y in ys]

    z_scale = np.sqrt(np.mean(np.vstack([y - y.mean(0) for y in ys]) ** 2, axis=0))
    v_scale = np.sqrt(np.mean(np.vstack([np.diff(y, axis=0) for y in ys]) ** 2, axis=0)) / z_scale
    channel_map = None
    if isinstance(channels, str):
        assert output_map is not None
        channels_name = channels
        channels = output_map                  # y = y'·output_mapᵀ: each measured output, a row
        if channels_name == "outputs+differences":
            pairs = np.array([np.eye(p)[i] - np.eye(p)[j] for i in range(p) for j in range(i + 1, p)])
            channels = np.vstack([output_map, pairs @ output_map])
    if channels is not None:
        d = np.atleast_2d(np.asarray(channels, float))
        if d.shape[1] != p:
            raise ValueError(f"feedback nonlinearity: channels must be [k, {p}], got {d.shape}")
        d = d * z_scale[None, :]
        zs = [(y - y.mean(0)) / z_scale for y in ys]
        rms = np.sqrt(np.mean(np.vstack([z @ d.T for z in zs]) ** 2, axis=0))
        if np.any(rms <= 0):
            raise ValueError("feedback nonlinearity: a channel direction has no output along it")
        d = d / rms[:, None]
        channel_map = np.vstack([np.eye(p), d])
        v_scale = np.concatenate([v_scale, np.sqrt(np.mean(np.vstack([np.diff(z @ d.T, axis=0) for z in zs]) ** 2,
                                                           axis=0))])
    P = np.eye(p) if channel_map is None else channel_map
    gram = rhs = None
    for u, y in zip(us, ys):
        uw = np.concatenate([u[-period:], u])
        yw = (np.concatenate([y[-period:], y]) / z_scale) @ P.T
        v = np.diff(yw, axis=0, prepend=yw[:1]) / v_scale
        signals = np.hstack([uw, _features(yw, v, features)]) if features else uw
        X = _modal_bank(poles, dt, signals)[period:]
        w = 1.0 / float(np.std(y))
        X, b = X * w, y * w
        gram = X.T @ X if gram is None else gram + X.T @ X
        rhs = X.T @ b if rhs is None else rhs + X.T @ b
    assert gram is not None and rhs is not None
    sc = np.sqrt(np.diag(gram))
    sc[sc == 0] = 1.0
    theta = np.linalg.solve(gram / np.outer(sc, sc) + 1e-12 * np.eye(len(sc)), rhs / sc[:, None]) / sc[:, None]
    return FeedbackNonlinearModel(poles=poles, dt=float(dt), features=features, z_scale=z_scale, v_scale=v_scale,
                                  theta=theta, n_inputs=m, output_map=output_map, channel_map=channel_map)


def add_channels(model: FeedbackNonlinearModel, directions: np.ndarray, y_records: Sequence[np.ndarray]
                 ) -> FeedbackNonlinearModel:
    """``model`` with more nonlinear channels — each a direction through its scaled outputs, fed through every
    feature — whose coefficients are zero: the same model (identical simulation), a start from which the
    simulation-error refinement can only lower its loss (``output_error.refine_output_error`` with
    ``refine_channels``: the directions are learnt too).

    Parameters
    ----------
    model : FeedbackNonlinearModel
        The model to widen (e.g. the refined elementwise fit).
    directions : ndarray
        ``[k, p]``: the new channels as combinations of the model outputs ``y'`` (the outputs, or the actuator
        coordinates of a model that has an ``output_map``); each is rescaled to unit RMS over ``y_records`` (so its
        features stay of order one, as the existing channels').
    y_records : sequence of ndarray
        Measured output records ``[T, p]`` (training), for the scales.

    Returns
    -------
    FeedbackNonlinearModel
        ``n_channels`` grown by ``k``; ``theta`` with zero rows for the new feature banks.

    Raises
    ------
    ValueError
        Directions of the wrong width, or a direction with no output along it.
    """
    d = np.atleast_2d(np.asarray(directions, float))
    p, nq, m = model.n_outputs, model.n_channels, model.n_inputs
    if d.shape[1] != p:
        raise ValueError(f"add channels: directions must be [k, {p}], got {d.shape}")
    d = d * model.z_scale[None, :]                    # on the scaled outputs the channels are computed from
    ys = [np.asarray(y, float) for y in y_records]
    if model.output_map is not None:
        ys = [y @ np.linalg.inv(model.output_map).T for y in ys]
    zs = [(y - y.mean(0)) / model.z_scale for y in ys]
    rms = np.sqrt(np.mean(np.vstack([z @ d.T for z in zs]) ** 2, axis=0))
    if np.any(rms <= 0):
        raise ValueError("add channels: a direction has no output along it on the records given")
    d = d / rms[:, None]
    v_new = np.sqrt(np.mean(np.vstack([np.diff(z @ d.T, axis=0) for z in zs]) ** 2, axis=0))
    ns = _n_states(model.poles)
    nf, k = len(model.features), len(d)
    theta = np.zeros(((m + nf * (nq + k)) * ns, p))
    theta[:m * ns] = model.theta[:m * ns]
    for f in range(nf):
        old = model.theta[(m + f * nq) * ns:(m + (f + 1) * nq) * ns]
        theta[(m + f * (nq + k)) * ns:(m + f * (nq + k) + nq) * ns] = old
    return FeedbackNonlinearModel(poles=model.poles, dt=model.dt, features=model.features, z_scale=model.z_scale,
                                  v_scale=np.concatenate([model.v_scale, v_new]), theta=theta, n_inputs=m,
                                  output_map=model.output_map,
                                  channel_map=np.vstack([model.channel_matrix(), d]))


def benchmark_nrmse_percent(y: Sequence[np.ndarray], y_hat: Sequence[np.ndarray], period: int,
                            n_init: int = 0) -> float:
    """The FSM benchmark's NRMSE [%]: per output channel, realization and period, the RMS of the error over the
    standard deviation of the measured output (the first ``n_init`` samples of each period left out), averaged
    (``nonlinear_benchmarks.error_metrics.NRMSE``, averaged as in the data set's ``analyze_models`` notebook)."""
    vals = []
    for yy, hh in zip(y, y_hat):
        yy, hh = np.asarray(yy, float), np.asarray(hh, float)
        for k in range(len(yy) // period):
            a, b = yy[k * period + n_init:(k + 1) * period], hh[k * period + n_init:(k + 1) * period]
            vals.append(np.sqrt(np.mean((a - b) ** 2, axis=0)) / np.std(a, axis=0))
    return 100.0 * float(np.mean(vals))
