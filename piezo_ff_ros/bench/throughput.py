"""Throughput of every core stage and of the full chain, next to naive baselines (the maths of ``piezo-ff bench``).

Every stage is run the way the nodes run it — streaming blocks with carried state — on a periodic 2-axis signal
(10 s buffer replayed; tones at 0.1, 1 and 13 Hz: creep-, scan- and vibration-range), and timed by wall clock,
best of ``repeats`` (the machine may be shared; CPU time is reported too).  In the same run, the same maths is
timed done naively on a short slice (``baseline_duration``) and extrapolated:

* a plain per-sample Python loop (numpy per sample) for every stage, linear parts as dense ``x ← A x + B u`` with
  (A, B, C, D) from ``control.c2d(…, 'zoh')`` of the continuous realisation;
* python-control's ``forced_response`` on those ZOH-discretised linear parts (the nonlinear stages stay as loops).

The plant, the cascade and the full chain are :class:`~piezo_ff_ros.core.chain.Chain` objects, so they run fused
(one compiled pass per block) as they do everywhere.
"""
from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Protocol

import numpy as np

if TYPE_CHECKING:   # annotations only: run_benchmark times the imports of the core itself
    from ..core.compensators.cascade import CompensatorCascade
    from ..core.config import PiezoConfig

__all__ = ["run_benchmark"]

_BUFFER_S = 10.0          # length of the replayed input (every tone is periodic in it)
_TONES_HZ = (0.1, 1.0, 13.0)


class _Proc(Protocol):
    """Anything streamed by the benchmark: ``process(block) -> block``."""

    def process(self, x: np.ndarray, /) -> np.ndarray: ...


# ----------------------------------------------------------------------------------------------------------------
# naive baselines: the same maths, one sample at a time in Python (numpy per sample)
# ----------------------------------------------------------------------------------------------------------------

def _naive_increment(p: dict[str, np.ndarray], h: np.ndarray, du: np.ndarray) -> np.ndarray:
    """One explicit Bouc-Wen step: ``A dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)``."""
    duh = p["P"] @ du
    ah, ad = np.abs(h), np.abs(duh)
    return p["A"] @ du - p["B"] @ (ad * h) - p["Gamma"] @ (duh * ah) - p["Delta1"] @ (duh * h) - p["Delta2"] @ (ad * ah)


def _naive_exact(p: dict[str, np.ndarray], h: np.ndarray, du: np.ndarray, sigma: float) -> np.ndarray:
    """h at the end of the straight step ``du``: in each sign orthant of h the increment's ODE is linear,
    ``dh/dλ = A·dU + M·h``, solved by ``expm`` of the augmented matrix; a sign change of h is located by ``brentq``
    and the path continues in the next orthant (the kernels' exact path, written plainly)."""
    import scipy.linalg
    import scipy.optimize
    q = p["P"] @ du
    a = p["A"] @ du
    n = len(h)
    B, G, D1, D2 = p["B"], p["Gamma"], p["Delta1"], p["Delta2"]
    tau_max = min(1.0, 0.5 / (sigma * float(np.max(np.abs(q)))))
    h = np.array(h, float)
    lam = 0.0
    while lam < 1.0:
        s = np.sign(h)
        M = -(np.abs(q)[None, :] * (B + D2 * s[None, :]) + q[None, :] * (G * s[None, :] + D1))
        if np.any(s == 0):
            d = a + M @ h
            s = np.where(s == 0, np.where(d < 0, -1.0, 1.0), s)
            M = -(np.abs(q)[None, :] * (B + D2 * s[None, :]) + q[None, :] * (G * s[None, :] + D1))
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n] = M
        aug[:n, n] = a

        def flow(t: float, aug: np.ndarray = aug, h: np.ndarray = h) -> np.ndarray:
            out: np.ndarray = (scipy.linalg.expm(aug * t) @ np.r_[h, 1.0])[:n]
            return out
        tau = min(1.0 - lam, tau_max)
        end = flow(tau)
        crossed = [j for j in range(n) if s[j] * end[j] < 0]
        if not crossed:
            h, lam = end, lam + tau
            continue
        tc, jc = min((scipy.optimize.brentq(lambda t, j=j: float(flow(t)[j]), 0.0, tau, xtol=1e-18, rtol=1e-15), j)
                     for j in crossed)
        h = flow(tc)
        h[jc] = 0.0
        lam += tc
    return h


def _naive_path(p: dict[str, np.ndarray], h: np.ndarray, du: np.ndarray) -> np.ndarray:
    """h after the step ``du`` along its straight path: one explicit step while ``κ = σ·max|dÛ| ≤ KAPPA_MAX``, the
    exact path beyond ``2·KAPPA_MAX`` (:func:`_naive_exact`), blended in between (the kernels' rule, written
    plainly)."""
    from ..core.kernels.bouc_wen import KAPPA_MAX
    sigma = float(np.max(np.sum(np.abs(p["B"]) + np.abs(p["Gamma"]) + np.abs(p["Delta1"]) + np.abs(p["Delta2"]),
                                axis=1)))
    x = sigma * float(np.max(np.abs(p["P"] @ du)))
    one = h + _naive_increment(p, h, du)
    if not x > KAPPA_MAX:
        return one
    exact = _naive_exact(p, h, du, sigma)
    w = min(x / KAPPA_MAX - 1.0, 1.0)
    out: np.ndarray = one + w * (exact - one)
    return out


def _naive_refine(p: dict[str, np.ndarray], h: np.ndarray, r: np.ndarray, du: np.ndarray) -> np.ndarray:
    """Newton's chord iterations (one finite-difference Jacobian) on ``Dp·du − (h' − h) = r`` for the path
    increment, from the one-step solution ``du``; nothing to do when that takes one step."""
    from ..core.kernels.bouc_wen import KAPPA_MAX
    sigma = float(np.max(np.sum(np.abs(p["B"]) + np.abs(p["Gamma"]) + np.abs(p["Delta1"]) + np.abs(p["Delta2"]),
                                axis=1)))
    if not sigma * float(np.max(np.abs(p["P"] @ du))) > KAPPA_MAX:
        return du

    def f(d: np.ndarray) -> np.ndarray:
        return p["Dp"] @ d - (_naive_path(p, h, d) - h) - r
    f0 = f(du)
    eps = 1e-7 * (1.0 + np.max(np.abs(du)))
    J = np.column_stack([(f(du + eps * e) - f0) / eps for e in np.eye(len(du))])
    for _ in range(50):
        step = np.linalg.solve(J, -f0)
        du = du + step
        if not np.max(np.abs(step)) > 1e-13 * np.max(np.abs(du)):
            break
        f0 = f(du)
    return du


class _NaiveBoucWen:
    """``h ← h + A dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)`` along the voltage path
    (:func:`_naive_path`), ``Y = Dp U − h``, sample by sample."""

    def __init__(self, p: dict[str, np.ndarray]) -> None:
        self.p = p
        self.h = np.zeros(p["Dp"].shape[0])
        self.u_prev: np.ndarray | None = None

    def process(self, u: np.ndarray) -> np.ndarray:
        p = self.p
        y = np.empty((len(u), p["Dp"].shape[0]))
        for k in range(len(u)):
            uk = u[k]
            if self.u_prev is None:
                self.u_prev = uk.copy()
            self.h = _naive_path(p, self.h, uk - self.u_prev)
            self.u_prev = uk.copy()
            y[k] = p["Dp"] @ uk - self.h
        return y


class _NaiveHysteresisCompensator:
    """``U = Dp⁻¹(Y_H + h)`` solved exactly per sample (sign pattern by sign pattern, ``np.linalg.solve``)."""

    def __init__(self, p: dict[str, np.ndarray], exact: bool = True) -> None:
        self.p = p
        self.exact = exact
        self.Dp_pinv = np.linalg.pinv(p["Dp"])
        n = p["Dp"].shape[0]
        self.h = np.zeros(n)
        self.u_prev: np.ndarray | None = None
        self.signs = np.ones(n)
        self.patterns = [np.array([1.0 if (q >> i) & 1 else -1.0 for i in range(n)]) for q in range(1 << n)]

    def process(self, yh: np.ndarray) -> np.ndarray:
        p = self.p
        u = np.empty((len(yh), p["Dp"].shape[1]))
        for k in range(len(yh)):
            if self.u_prev is None:
                self.u_prev = self.Dp_pinv @ yh[k]
                u[k] = self.u_prev
                continue
            du = None
            if self.exact:
                r = yh[k] + self.h - p["Dp"] @ self.u_prev
                ah = np.abs(self.h)
                for s in [self.signs, *self.patterns]:
                    W = p["B"] * (s * self.h) + p["Gamma"] * ah + p["Delta1"] * self.h + p["Delta2"] * (s * ah)
                    try:
                        cand = np.linalg.solve(p["Dp"] - p["A"] + W @ p["P"], r)
                    except np.linalg.LinAlgError:
                        continue
                    if np.all((p["P"] @ cand) * s >= 0.0):
                        du, self.signs = cand, s
                        break
                if du is not None:
                    du = _naive_refine(p, self.h, r, du)
            if du is None:
                du = self.Dp_pinv @ (yh[k] + self.h) - self.u_prev
            self.h = _naive_path(p, self.h, du)
            self.u_prev = self.u_prev + du
            u[k] = self.u_prev
        return u


class _NaiveLTI:
    """Dense ``y = C x + D u; x ← A x + B u`` per sample."""

    def __init__(self, dsys: Any, feedthrough: np.ndarray | None = None) -> None:
        self.A, self.B, self.C, self.D = (np.asarray(m, float) for m in (dsys.A, dsys.B, dsys.C, dsys.D))
        if feedthrough is not None:
            self.D = self.D + feedthrough
        self.x = np.zeros(self.A.shape[0])

    def process(self, u: np.ndarray) -> np.ndarray:
        y = np.empty((len(u), self.C.shape[0]))
        for k in range(len(u)):
            y[k] = self.C @ self.x + self.D @ u[k]
            self.x = self.A @ self.x + self.B @ u[k]
        return y


class _NaiveCreepCompensator:
    """``Y_H = K⁻¹(Y_L − Cr x)``, ``x ← A x + B Y_H`` per sample."""

    def __init__(self, dsys: Any, K: np.ndarray) -> None:
        self.A, self.B, self.C = (np.asarray(m, float) for m in (dsys.A, dsys.B, dsys.C))
        self.Kinv = np.linalg.inv(K)
        self.x = np.zeros(self.A.shape[0])

    def process(self, yl: np.ndarray) -> np.ndarray:
        yh = np.empty_like(yl)
        for k in range(len(yl)):
            yh[k] = self.Kinv @ (yl[k] - self.C @ self.x)
            self.x = self.A @ self.x + self.B @ yh[k]
        return yh


class _ForcedResponse:
    """python-control's ``forced_response`` on a discrete system, state carried between calls."""

    def __init__(self, dsys: Any, feedthrough: np.ndarray | None = None) -> None:
        import control

        self.control = control
        D = np.asarray(dsys.D, float) + (feedthrough if feedthrough is not None else 0.0)
        self.sys = control.ss(dsys.A, dsys.B, dsys.C, D, dsys.dt)
        self.x = np.zeros(self.sys.nstates)

    def process(self, u: np.ndarray) -> np.ndarray:
        n = len(u)
        T = np.arange(n) * self.sys.dt
        r = self.control.forced_response(self.sys, T=T, U=u.T, X0=self.x, return_x=True)
        # state after the last sample (forced_response returns x up to the last input's time)
        self.x = self.sys.A @ r.states[:, -1] + self.sys.B @ u[-1]
        y: np.ndarray = np.atleast_2d(r.outputs).T
        return y


class _Series:
    def __init__(self, *stages: Any) -> None:
        self.stages = stages

    def reset(self) -> None:
        for s in self.stages:
            s.reset()

    def process(self, x: np.ndarray) -> np.ndarray:
        for s in self.stages:
            x = s.process(x)
        return x


# ----------------------------------------------------------------------------------------------------------------
# measurement
# ----------------------------------------------------------------------------------------------------------------

@dataclass
class _Stage:
    name: str
    label: str
    make: Callable[[], _Proc]                     # () -> streaming stage (compiled core)
    kind: str                                     # 'voltage' or 'length' input
    naive: Callable[[], _Proc] | None = None      # () -> per-sample Python loop stage
    forced: Callable[[], _Proc] | None = None     # () -> forced_response variant (linear parts), or None
    notes: list[str] = field(default_factory=list)


def _signals(cfg: PiezoConfig, fs: float) -> dict[str, np.ndarray]:
    n = int(round(_BUFFER_S * fs))
    t = np.arange(n) / fs
    base = np.column_stack([
        0.6 * np.sin(2 * np.pi * _TONES_HZ[0] * t) + 0.3 * np.sin(2 * np.pi * _TONES_HZ[1] * t + 0.4)
        + 0.05 * np.sin(2 * np.pi * _TONES_HZ[2] * t),
        0.6 * np.cos(2 * np.pi * _TONES_HZ[0] * t) + 0.3 * np.sin(2 * np.pi * _TONES_HZ[1] * t + 1.9)
        + 0.05 * np.cos(2 * np.pi * _TONES_HZ[2] * t)])
    return {"voltage": np.ascontiguousarray(160.0 * base), "length": np.ascontiguousarray(15e-6 * base)}


def _blocks(buf: np.ndarray, block: int) -> list[np.ndarray]:
    """Views of ``buf`` cut in blocks of ``block`` samples, wrapping around (the buffer is periodic)."""
    n = len(buf)
    out: list[np.ndarray] = []
    k = 0
    while True:
        if k + block <= n:
            out.append(buf[k:k + block])
        else:
            out.append(np.ascontiguousarray(np.vstack([buf[k:], buf[:block - (n - k)]])))
        k = (k + block) % n
        if k == 0:  # back at the start: the cycle of blocks repeats
            return out


def _stream(stage: _Proc, blocks: list[np.ndarray], n_blocks: int) -> tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    nb = len(blocks)
    for i in range(n_blocks):
        stage.process(blocks[i % nb])
    return time.perf_counter() - w0, time.process_time() - c0


def _timed_stream(make: Callable[[], _Proc], buf: np.ndarray, block: int, n_total: int,
                  repeats: int) -> tuple[int, list[float], list[float]]:
    blocks = _blocks(buf, block)
    n_blocks = max(1, int(round(n_total / block)))
    walls: list[float] = []
    cpus: list[float] = []
    for _ in range(repeats):
        stage = make()
        w, c = _stream(stage, blocks, n_blocks)
        walls.append(w)
        cpus.append(c)
    return n_blocks * block, walls, cpus


def _rate(n: float, seconds: float) -> float:
    return n / seconds if seconds > 0 else float("inf")


def _machine() -> dict[str, Any]:
    import scipy

    import control

    try:
        import numba
        numba_version: str | None = numba.__version__
    except ImportError:  # the core still runs (pure-Python fallback), only slowly
        numba_version = None

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load: list[float] | None = list(os.getloadavg())
    except OSError:
        load = None
    return {"cpu": cpu, "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba_version,
            "control": control.__version__, "platform": platform.platform(), "loadavg_1_5_15": load}


def _kernels() -> dict[str, Any]:
    """The compiled kernels of the core chain (numba dispatchers, or plain functions without numba)."""
    from ..core.kernels import bouc_wen, modal, specialise

    mods = {"modal": modal, "bouc_wen": bouc_wen}
    names = ["modal.bank_run", "modal.bank_run_2x2", "modal.inverse_affine_run", "modal.inverse_affine_run_2x2",
             "bouc_wen.bw_model_run", "bouc_wen.bw_model_run_2x2", "bouc_wen.bw_comp_run",
             "bouc_wen.bw_comp_run_2x2"]
    out = {name: getattr(mods[name.split(".")[0]], name.split(".")[1]) for name in names}
    out.update(specialise.generated_kernels())  # loops specialised to the stages' structure, fused passes
    return out


def _jit_stats() -> dict[str, dict[str, int]]:
    out = {}
    for name, k in _kernels().items():
        st = getattr(k, "stats", None)
        if st is None:
            continue
        out[name] = {"cache_hits": int(sum(st.cache_hits.values())),
                     "cache_misses": int(sum(st.cache_misses.values()))}
    return out


def _controller(cfg: PiezoConfig, hinf: bool, echo: bool) -> tuple[Any, dict[str, Any]]:
    """The H∞ controller (synthesised and reduced, timed) or, when that is unavailable, a labelled stand-in."""
    import control

    info: dict[str, Any] = {"hinf_synthesis_s": None, "hinf_wall_s": None, "controller": None, "controller_order": None,
            "note": None}
    design = None
    if hinf:
        try:
            from ..core.synthesis.hinf import synthesize_hinf
        except ImportError as exc:
            info["note"] = f"H∞ synthesis unavailable ({exc})"
        else:
            if echo:
                print("H∞ synthesis + reduction …", flush=True)
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                design = synthesize_hinf(cfg.dynamics.G_L, cfg.vibration)
            except Exception as exc:  # a failed design must not stop the throughput figures
                info["note"] = f"H∞ synthesis failed ({type(exc).__name__}: {exc})"
            info["hinf_wall_s"] = time.perf_counter() - t0
            info["hinf_cpu_s"] = time.process_time() - c0  # CPU time of this process (all its threads)
        if design is not None:
            info["hinf_synthesis_s"] = float(getattr(design, "synthesis_s", info["hinf_wall_s"]))
            k = control.ss(design.controller)
            info.update(controller="H∞ (synthesize_hinf, reduced)", controller_order=int(k.nstates))
            try:  # γ, orders, verification time … when the design object offers them
                info["design"] = design.as_dict()
            except Exception:  # noqa: BLE001 - optional detail
                pass
            return k, info
    else:
        info["note"] = "H∞ synthesis skipped (--no-hinf)"
    order = int(cfg.vibration.order)
    stand_in = control.balred(cfg.dynamics.G_L.to_control(), order)
    info.update(controller=f"STAND-IN: control.balred(G_L, {order}) (not the H∞ design; same order and I/O)",
                controller_order=int(stand_in.nstates))
    return stand_in, info


def _time_core_imports() -> float:
    """Wall time [s] of importing python-control and the core's stage modules (the first import in this process;
    later imports of them are cached)."""
    t_import = time.perf_counter()
    import control  # noqa: F401

    from ..core.compensators.cascade import CompensatorCascade  # noqa: F401
    from ..core.compensators.creep import CreepCompensator  # noqa: F401
    from ..core.compensators.hysteresis import HysteresisCompensator  # noqa: F401
    from ..core.compensators.vibration import VibrationCompensator  # noqa: F401
    from ..core.config import load_config  # noqa: F401
    from ..core.models.bouc_wen import BoucWenModel  # noqa: F401
    from ..core.models.creep import CreepModel  # noqa: F401
    from ..core.models.dynamics import DynamicsModel  # noqa: F401
    from ..core.models.plant import Plant  # noqa: F401
    from ..core.chain import Chain  # noqa: F401
    from ..core._jit import HAVE_NUMBA  # noqa: F401
    return time.perf_counter() - t_import


@dataclass(frozen=True)
class _Baselines:
    """The linear parts as the baselines run them: ZOH discretisations (dense realisations) of Cr, G_L and the
    controller, and the creep compensator ``(K + Cr)⁻¹`` as a discrete state space; with the Bouc-Wen arrays."""

    hp: dict[str, np.ndarray]     #: Bouc-Wen parameter arrays
    exact: bool                   #: the hysteresis compensator solves its loop exactly
    K: np.ndarray                 #: creep static gain
    cr_d: Any                     #: Cr, ZOH
    gl_d: Any                     #: G_L, ZOH
    k_d: Any                      #: the controller, ZOH
    ci_d: Any                     #: (K + Cr)⁻¹, discrete

    def naive_cascade(self) -> _Series:
        """Controller → creep compensator → hysteresis compensator, per-sample loops."""
        return _Series(_NaiveLTI(self.k_d), _NaiveCreepCompensator(self.cr_d, self.K),
                       _NaiveHysteresisCompensator(self.hp, self.exact))

    def naive_plant(self) -> _Series:
        """Bouc-Wen → K + Cr → G_L, per-sample loops."""
        return _Series(_NaiveBoucWen(self.hp), _NaiveLTI(self.cr_d, feedthrough=self.K), _NaiveLTI(self.gl_d))

    def forced_cascade(self) -> _Series:
        """The cascade with ``forced_response`` for its linear parts."""
        return _Series(_ForcedResponse(self.k_d), _ForcedResponse(self.ci_d),
                       _NaiveHysteresisCompensator(self.hp, self.exact))

    def forced_plant(self) -> _Series:
        """The plant with ``forced_response`` for its linear parts."""
        return _Series(_NaiveBoucWen(self.hp), _ForcedResponse(self.cr_d, feedthrough=self.K),
                       _ForcedResponse(self.gl_d))


def _baselines(cfg: PiezoConfig, ctrl: Any) -> _Baselines:
    """The baselines' realisations of ``cfg`` with the controller ``ctrl`` (continuous → ZOH at ``cfg.dt``).

    Parameters
    ----------
    cfg : PiezoConfig
        The piezo config.
    ctrl : control.StateSpace
        The vibration compensator (continuous).

    Returns
    -------
    _Baselines
    """
    import control

    dt = cfg.dt
    K = np.array(cfg.creep.K, float)
    cr_d = control.c2d(cfg.creep.Cr.to_control(), dt, "zoh")
    gl_d = control.c2d(cfg.dynamics.G_L.to_control(), dt, "zoh")
    k_d = control.c2d(ctrl, dt, "zoh")
    # the creep compensator is linear too: (K + Cr)⁻¹ as a discrete state space
    Kinv = np.linalg.inv(K)
    ci_d = control.ss(cr_d.A - cr_d.B @ Kinv @ cr_d.C, cr_d.B @ Kinv, -Kinv @ cr_d.C, Kinv, dt)
    return _Baselines(cfg.hysteresis.arrays(), cfg.cascade.hysteresis_loop == "exact", K, cr_d, gl_d, k_d, ci_d)


def _stages(cfg: PiezoConfig, ctrl: Any, ctrl_order: Any, b: _Baselines) -> list[_Stage]:
    """Every stage benchmarked, in report order (the full chain last), each with its baselines.

    Parameters
    ----------
    cfg : PiezoConfig
        The piezo config.
    ctrl : control.StateSpace
        The vibration compensator.
    ctrl_order : int
        Its order (in the stage's label).
    b : _Baselines
        The baselines' realisations.

    Returns
    -------
    list of _Stage
    """
    from ..core.compensators.cascade import CompensatorCascade
    from ..core.compensators.creep import CreepCompensator
    from ..core.compensators.hysteresis import HysteresisCompensator
    from ..core.compensators.vibration import VibrationCompensator
    from ..core.models.bouc_wen import BoucWenModel
    from ..core.models.creep import CreepModel
    from ..core.models.dynamics import DynamicsModel
    from ..core.models.plant import Plant
    from ..core.chain import Chain

    dt, loop, hp, K = cfg.dt, cfg.cascade.hysteresis_loop, b.hp, b.K
    ck = (ctrl.A, ctrl.B, ctrl.C, ctrl.D)

    def cascade() -> CompensatorCascade:
        return CompensatorCascade(cfg, controller=ck)

    return [
        _Stage("bouc_wen", "Bouc-Wen model", lambda: BoucWenModel(cfg.hysteresis), "voltage",
               naive=lambda: _NaiveBoucWen(hp)),
        _Stage("hysteresis_comp", f"hysteresis compensator ({loop})",
               lambda: HysteresisCompensator(cfg.hysteresis, loop), "length",
               naive=lambda: _NaiveHysteresisCompensator(hp, b.exact)),
        _Stage("creep_model", "creep model", lambda: CreepModel(cfg.creep, dt), "length",
               naive=lambda: _NaiveLTI(b.cr_d, feedthrough=K), forced=lambda: _ForcedResponse(b.cr_d, feedthrough=K)),
        _Stage("creep_comp", "creep compensator", lambda: CreepCompensator(cfg.creep, dt), "length",
               naive=lambda: _NaiveCreepCompensator(b.cr_d, K), forced=lambda: _ForcedResponse(b.ci_d)),
        _Stage("dynamics", "dynamics G_L", lambda: DynamicsModel(cfg.dynamics, dt), "length",
               naive=lambda: _NaiveLTI(b.gl_d), forced=lambda: _ForcedResponse(b.gl_d)),
        _Stage("vibration_comp", f"vibration compensator (order {ctrl_order})",
               lambda: VibrationCompensator(*ck, dt), "length",
               naive=lambda: _NaiveLTI(b.k_d), forced=lambda: _ForcedResponse(b.k_d)),
        _Stage("plant", "plant (hysteresis+creep+dynamics)", lambda: Plant(cfg), "voltage",
               naive=b.naive_plant, forced=b.forced_plant),
        _Stage("cascade", "compensator cascade", cascade, "length", naive=b.naive_cascade, forced=b.forced_cascade),
        _Stage("full_chain", "full chain (cascade + plant)",
               lambda: Chain([("cascade", cascade()), ("plant", Plant(cfg))]), "length",
               naive=lambda: _Series(b.naive_cascade(), b.naive_plant()),
               forced=lambda: _Series(b.forced_cascade(), b.forced_plant())),
    ]


@dataclass(frozen=True)
class _Sizes:
    """How much each run streams."""

    fs: float                     #: sample rate [Hz]
    block: int                    #: samples per process() call of the timed runs
    repeats: int                  #: timed repeats (best reported)
    n_total: int                  #: samples per timed run
    n_base: int                   #: samples the baselines run (extrapolated)


def _first_calls(stages: list[_Stage], sig: dict[str, np.ndarray]) -> dict[str, float]:
    """Wall time [s] of each stage's first ``process`` call on 8 samples: the numba cache load (or compile), kept
    apart from the steady state.

    Parameters
    ----------
    stages : list of _Stage
        In order (kernels shared with an earlier stage are loaded by then).
    sig : dict
        The input signals by kind.

    Returns
    -------
    dict
        Seconds per stage name.
    """
    first_call: dict[str, float] = {}
    for st in stages:
        x = sig[st.kind][:8]
        t0 = time.perf_counter()
        st.make().process(x)
        first_call[st.name] = time.perf_counter() - t0
    return first_call


def _measure_stage(st: _Stage, sig: dict[str, np.ndarray], sizes: _Sizes, first_call_s: float,
                   echo: bool) -> dict[str, Any]:
    """One stage's figures: setup time, the timed streaming runs, and its baselines on a slice.

    Parameters
    ----------
    st : _Stage
        The stage.
    sig : dict
        The input signals by kind.
    sizes : _Sizes
        Run lengths.
    first_call_s : float
        Its first call's time (:func:`_first_calls`).
    echo : bool
        Print the stage's label first.

    Returns
    -------
    dict
        ``results['stages'][name]`` of the benchmark.
    """
    if echo:
        print(f"  {st.label} …", flush=True)
    fs = sizes.fs
    t0 = time.perf_counter()
    st.make()
    setup_s = time.perf_counter() - t0
    n, walls, cpus = _timed_stream(st.make, sig[st.kind], sizes.block, sizes.n_total, sizes.repeats)
    best = min(walls)
    r: dict[str, Any] = {"label": st.label, "samples": n, "block": sizes.block, "repeats": sizes.repeats,
                         "setup_s": setup_s, "first_call_s": first_call_s,
                         "wall_s": walls, "cpu_s": cpus, "samples_per_s": _rate(n, best), "rt_factor": _rate(n, best) / fs,
                         "cpu_rt_factor": _rate(n, min(cpus)) / fs}
    r.update(_baseline_figures(st, sig[st.kind][:sizes.n_base], sizes))
    return r


def _baseline_figures(st: _Stage, x: np.ndarray, sizes: _Sizes) -> dict[str, dict[str, Any] | None]:
    """The stage's baselines run once on ``x``, extrapolated, their output compared with the compiled stage's.

    Parameters
    ----------
    st : _Stage
        The stage.
    x : ndarray
        The slice the baselines run (the first ``sizes.n_base`` samples of the input).
    sizes : _Sizes
        ``n_base`` and ``fs`` of the figures.

    Returns
    -------
    dict
        ``{'naive': {…} or None, 'forced_response': {…} or None}``.
    """
    n_base, fs = sizes.n_base, sizes.fs
    y_fast = st.make().process(x)
    scale = max(float(np.max(np.abs(y_fast))), 1e-300)
    out: dict[str, dict[str, Any] | None] = {}
    for kind, mk in (("naive", st.naive), ("forced_response", st.forced)):
        if mk is None:
            out[kind] = None
            continue
        stage = mk()
        w0 = time.perf_counter()
        y = stage.process(x)
        w = time.perf_counter() - w0
        out[kind] = {"samples": n_base, "wall_s": w, "samples_per_s": _rate(n_base, w),
                     "rt_factor": _rate(n_base, w) / fs, "extrapolated_from_s": n_base / fs,
                     "max_rel_diff": float(np.max(np.abs(y - y_fast)) / scale)}
    return out


def _small_block_run(full_chain: _Stage, buf: np.ndarray, small_block: int, sizes: _Sizes,
                     echo: bool) -> dict[str, Any]:
    """The full chain in node-sized blocks (per-call overhead shows), at most 60 s simulated (it is the slow run).

    Parameters
    ----------
    full_chain : _Stage
        The full chain stage.
    buf : ndarray
        Its input (length signal).
    small_block : int
        Samples per block.
    sizes : _Sizes
        Run length and repeats.
    echo : bool
        Print a line first.

    Returns
    -------
    dict
        ``results['stages']['full_chain_small_blocks']``.
    """
    if echo:
        print(f"  full chain, {small_block}-sample blocks …", flush=True)
    fs = sizes.fs
    n_small = min(sizes.n_total, int(round(60.0 * fs)))
    n, walls, cpus = _timed_stream(full_chain.make, buf, small_block, n_small, sizes.repeats)
    return {"label": f"full chain, {small_block}-sample blocks", "samples": n, "block": small_block,
            "repeats": sizes.repeats, "wall_s": walls, "cpu_s": cpus, "samples_per_s": _rate(n, min(walls)),
            "rt_factor": _rate(n, min(walls)) / fs, "cpu_rt_factor": _rate(n, min(cpus)) / fs}


def _figures(sizes: _Sizes, ctrl_info: dict[str, Any], import_s: float, jit: dict[str, Any],
             results: dict[str, dict[str, Any]], machine: dict[str, Any]) -> dict[str, Any]:
    """The benchmark's result (the JSON of ``piezo-ff bench --json``), headline figures from the full chain.

    Parameters
    ----------
    sizes : _Sizes
        Run lengths.
    ctrl_info : dict
        The controller's facts (:func:`_controller`).
    import_s : float
        Import time of the core.
    jit : dict
        First calls and numba cache statistics before and after them.
    results : dict
        Figures per stage.
    machine : dict
        The machine's facts.

    Returns
    -------
    dict
    """
    from ..core._jit import HAVE_NUMBA

    fc = results["full_chain"]
    return {
        "full_chain_rt_factor": fc["rt_factor"],
        "full_chain_cpu_rt_factor": fc["cpu_rt_factor"],  # per core of CPU time (robust to a shared machine)
        "baseline_rt_factor": fc["naive"]["rt_factor"],
        "baseline_forced_response_rt_factor": fc["forced_response"]["rt_factor"],
        "hinf_synthesis_s": ctrl_info["hinf_synthesis_s"],
        "full_chain_s_per_600s": 600.0 / fc["rt_factor"],
        "sample_rate": sizes.fs,
        "duration_s": sizes.n_total / sizes.fs,
        "baseline_duration_s": sizes.n_base / sizes.fs,
        "block": sizes.block,
        "controller": ctrl_info,
        "numba": HAVE_NUMBA,
        "import_s": import_s,
        "jit": jit,
        "stages": results,
        "machine": machine,
        "notes": [
            "sample = one time step of both axes; rt_factor = simulated s per wall s at sample_rate",
            "compiled stages: best wall time of the repeats (shared machine); cpu_rt_factor from process CPU time",
            "baselines run once on the first baseline_duration_s of the input and are extrapolated",
            "first_call_s: first process() call of each stage in this process (numba cache load or compile); "
            "kernels shared with an earlier stage are already loaded",
        ],
    }


def run_benchmark(duration: float = 600.0, repeats: int = 3, block: int = 20000, small_block: int = 200,
                  baseline_duration: float = 0.5, config: str | None = None, variant: str | None = None,
                  hinf: bool = True, echo: bool = False) -> dict[str, Any]:
    """Run every stage; return the figures (the JSON written by ``piezo-ff bench --json``)."""
    import_s = _time_core_imports()
    from ..core.config import load_config

    cfg = load_config(config, variant=variant)
    fs = cfg.sample_rate
    machine = _machine()
    ctrl, ctrl_info = _controller(cfg, hinf, echo)
    stages = _stages(cfg, ctrl, ctrl_info["controller_order"], _baselines(cfg, ctrl))

    sig = _signals(cfg, fs)
    # the baselines run on a slice of the signal buffer: at most all of it
    n_base = min(max(2, int(round(baseline_duration * fs))), len(sig["length"]))
    sizes = _Sizes(fs, block, repeats, int(round(duration * fs)), n_base)
    jit_before = _jit_stats()
    first_call = _first_calls(stages, sig)
    jit_after = _jit_stats()
    results = {st.name: _measure_stage(st, sig, sizes, first_call[st.name], echo) for st in stages}
    if small_block:
        results["full_chain_small_blocks"] = _small_block_run(stages[-1], sig["length"], small_block, sizes, echo)

    machine["loadavg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    jit = {"first_call_s": first_call, "cache_before": jit_before, "cache_after": jit_after}
    return _figures(sizes, ctrl_info, import_s, jit, results, machine)
