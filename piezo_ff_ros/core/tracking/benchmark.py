"""The ``piezo-ff track`` benchmark: known trajectories × methods × truth plants, in simulation (no ROS).

Methods (each ends in the same amplifier: ±voltage and slew, applied by the cascade exactly as the driver would):

- ``open``: ``U = Dp⁻¹·r`` (clamped);
- ``cascade``: the paper's cascade on r;
- ``preview``: :class:`~.preview.PreviewStage` (reference fed ``preview_samples`` ahead) in front of the cascade;
- ``learning``: preview + a correction learned by :class:`~.ilc.IterativeLearning` on the truth (measured with its
  sensor noise), then played once more with the sensor off — the figures are of that last, sensorless trial.

Truths: ``nominal`` (model = plant), ``asymmetric`` (generalized Bouc-Wen truth, the compensators keep the printed
symmetric model), ``noise_100nm`` (nominal plant, 100 nm RMS white sensor noise in the learning trials; the figures
are of the true displacement), ``identified`` (the compensators built from a config identified on the simulated
printed plant, :func:`~..commissioning.commission_sim`; the truth is the printed plant).

Every reference starts with a 0.1 s smooth lead-in from rest to its first sample.  Errors are the Euclidean
distance ``|y − r|`` (over every axis) read on a window: the last revolution of a circle, a helix or a sine, the lines
after the first outside the turnarounds of a raster, the whole of a spiral.  Any number of axes: the plane cases run
in the plane of the first two axes (:func:`on_stage`), a third axis adds a helix and a raster over a ramp, a single
axis tracks sines (:func:`benchmark_cases`).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..compensators.cascade import CompensatorCascade
from ..config import PiezoConfig
from ..models.plant import Plant
from ..trajectories import Circle, Hold, PerAxis, Ramp, Raster, Sine, Spiral, Trajectory, helix
from .ilc import ILCConfig, IterativeLearning, convergence_factor
from .linear import CascadeReplica, CompensatedModel, controller_matrices
from .preview import PreviewConfig, PreviewStage

__all__ = ["Case", "benchmark_cases", "on_stage", "run_benchmark", "METHODS", "TRUTHS", "LEAD_IN_S", "tracking_metrics", "TrackingModel"]

METHODS = ("open", "cascade", "preview", "learning")
TRUTHS = ("nominal", "asymmetric", "noise_100nm", "identified")
LEAD_IN_S = 0.1
NOISE_M = 100e-9


@dataclass(frozen=True)
class Case:
    """One benchmark trajectory: contract fields and the trajectory itself."""

    trajectory: str            #: circle | raster | spiral
    size_um: float             #: circle/spiral radius, raster width (= height)
    frequency_hz: float        #: revolution or line rate
    traj: Trajectory

    @property
    def label(self) -> str:
        """Short human-readable name, e.g. ``circle 20 µm 10 Hz``."""
        return f"{self.trajectory} {self.size_um:g} µm {self.frequency_hz:g} Hz"


def on_stage(traj: Trajectory, axes: Sequence[str]) -> Trajectory:
    """A plane trajectory (circle, raster, spiral on two axes) on a stage of ``axes``: in the plane of the first two
    axes, the others at rest (:class:`~..trajectories.PerAxis`); unchanged on a stage of those two axes."""
    axes = tuple(axes)
    if traj.axes == axes:
        return traj
    plane = dataclasses.replace(traj, axes=axes[:2], **({"fast_axis": axes[0]} if isinstance(traj, Raster) else {}))
    return plane if len(axes) == 2 else PerAxis([plane], axes=axes)


def benchmark_cases(quick: bool = False, axes: Sequence[str] = ("x", "y")) -> list[Case]:
    """Circles 20/30 µm at 1, 10, 50 Hz; raster 20 µm at 10 and 50 Hz lines; a 20 µm spiral at 10 Hz.

    On a stage of three axes or more they run in the plane of the first two, and two cases move the third: a helix
    (the 20 µm circle at 10 Hz over a 10 µm ramp) and a raster over a 10 µm ramp (``raster_z``).  A single axis
    tracks sines of the circles' amplitudes and frequencies instead."""
    um = 1e-6
    axes = tuple(axes)
    cases = []
    for size in ((20,) if quick else (20, 30)):
        for f in ((1, 10) if quick else (1, 10, 50)):
            revs = 2 if f == 1 else 4
            if len(axes) == 1:
                cases.append(Case("sine", size, f, Sine(amplitude=size * um, frequency=f, axis=axes[0],
                                                        duration=revs / f, axes=axes)))
            else:
                cases.append(Case("circle", size, f, on_stage(Circle(radius=size * um, frequency=f, revolutions=revs),
                                                              axes)))
    if len(axes) == 1:
        return cases
    for f in ((10,) if quick else (10, 50)):
        cases.append(Case("raster", 20, f, on_stage(Raster(width=20 * um, lines=6 if f == 10 else 12, line_rate=f),
                                                    axes)))
    cases.append(Case("spiral", 20, 10, on_stage(Spiral(radius=20 * um, frequency=10, revolutions=5), axes)))
    if len(axes) >= 3:
        rest = [Hold(value=0.0, duration=0.1, axes=axes[3:])] if len(axes) > 3 else []
        h = helix(20 * um, 10, 4, 10 * um, axes=(axes[0], axes[1], axes[2]))
        cases.append(Case("helix", 20, 10, PerAxis(list(h.parts) + rest, axes=axes)))
        ras = Raster(width=20 * um, lines=6, line_rate=10, axes=axes[:2], fast_axis=axes[0])
        ramp = Ramp(start=0.0, end=10 * um, duration=ras.duration, axes=axes[2:3])
        cases.append(Case("raster_z", 20, 10, PerAxis([ras, ramp] + rest, axes=axes)))
    return cases


def _raster(traj: Trajectory) -> Raster:
    """The raster of a raster case (itself, or its part on a stage of more axes)."""
    if isinstance(traj, Raster):
        return traj
    assert isinstance(traj, PerAxis)   # the raster cases carry a Raster, alone or as a part
    return next(p for p in traj.parts if isinstance(p, Raster))


def reference_with_lead_in(case: Case, fs: float) -> tuple[np.ndarray, int]:
    """``(r [N, axes], n_lead)``: a smoothstep from rest to the trajectory's first sample, then the trajectory."""
    n_lead = int(round(LEAD_IN_S * fs))
    _, body = case.traj.sample(fs)
    s = np.arange(n_lead) / n_lead
    ramp = (s * s * (3 - 2 * s))[:, None] * body[:1]
    return np.vstack([ramp, body]), n_lead


def evaluation_window(case: Case, r: np.ndarray, n_lead: int, fs: float) -> np.ndarray:
    """Boolean mask of the samples the errors are read on (see the module docstring)."""
    n = len(r)
    mask = np.zeros(n, bool)
    if case.trajectory in ("circle", "sine", "helix"):
        mask[n - int(round(fs / case.frequency_hz)):] = True
    elif case.trajectory in ("raster", "raster_z"):
        fast = r[:, case.traj.axes.index(_raster(case.traj).fast_axis)]
        acc = np.abs(np.gradient(np.gradient(fast)))
        mask[n_lead + int(round(fs / case.frequency_hz)):] = True
        mask &= acc < 1e-6 * acc.max()
    else:
        mask[n_lead:] = True
    return mask


def tracking_metrics(y: np.ndarray, r: np.ndarray, u: np.ndarray, mask: np.ndarray, fs: float) -> dict[str, float]:
    """Tracking figures of one run on the samples ``mask`` selects: RMS and max of the Euclidean error ``|y − r|``
    [µm], peak voltage [V] and peak slew [V/s] of ``u`` sampled at ``fs``."""
    e = np.linalg.norm(y[mask] - r[mask], axis=1)
    du = np.abs(np.diff(u, axis=0)) * fs
    return {"rms_error_um": float(np.sqrt(np.mean(e ** 2)) * 1e6), "max_error_um": float(e.max() * 1e6),
            "peak_voltage_v": float(np.abs(u).max()), "peak_slew_v_per_s": float(du.max()) if len(du) else 0.0}


@dataclass
class TrackingModel:
    """Everything built from one model config (the compensators' view of the actuator)."""

    cfg: PiezoConfig
    cascade: CompensatorCascade
    compensated: CompensatedModel
    preview: PreviewStage

    @staticmethod
    def build(cfg: PiezoConfig, preview_cfg: PreviewConfig) -> "TrackingModel":
        """The cascade (H∞ synthesised unless the config carries a controller), its compensated model and the
        preview stage, all for ``cfg`` with the amplifier's limits respected."""
        from ..identification.pipeline import synthesize_for

        cfg = dataclasses.replace(cfg, cascade=dataclasses.replace(cfg.cascade, respect_limits=True))
        # an identified G_L has its DC bound at ≈ 1: the same γ headroom as `piezo-ff commission` gives it
        casc = CompensatorCascade(cfg, None if cfg.vibration.controller is not None else synthesize_for(cfg)[0])
        ctrl = controller_matrices(casc)
        comp = CompensatedModel.from_config(cfg, ctrl)
        return TrackingModel(cfg, casc, comp, PreviewStage(cfg, ctrl, preview_cfg, model=comp))

    def shaped(self, r: np.ndarray, stage: PreviewStage | None = None) -> np.ndarray:
        """``r`` through the preview stage (fed ``preview_samples`` ahead, the tail held at the last sample)."""
        st = stage or self.preview
        st.reset()
        L = st.preview_samples
        ahead = np.vstack([r[L:], np.repeat(r[-1:], min(L, len(r)), axis=0)])[: len(r)]
        return st.process(ahead)

    def drive(self, plant: Plant, yr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(u, y)``: ``yr`` through the cascade, then the plant (both reset first)."""
        self.cascade.reset()
        plant.reset()
        u = self.cascade.process(yr)
        return u, plant.process(u)

    def open_loop(self, plant: Plant, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(u, y)`` with the static inverse gain only (clamped to the voltage limit)."""
        Dp_pinv = np.linalg.pinv(np.array(self.cfg.hysteresis.Dp, float))
        lim = self.cfg.limits
        u = np.clip(r @ Dp_pinv.T, -lim.voltage, lim.voltage)
        plant.reset()
        return u, plant.process(u)


def _truth_plant(printed: PiezoConfig, truth: str, noise: float, seed: int) -> Plant:
    from ..reproduce import truth_plant

    return truth_plant(printed, "asymmetric" if truth == "asymmetric" else "nominal", noise, seed)


def run_benchmark(printed: PiezoConfig, identified: PiezoConfig | None = None, quick: bool = False,
                  truths: tuple[str, ...] = TRUTHS, ilc: ILCConfig | None = None,
                  preview_cfg: PreviewConfig | None = None,
                  constrained: bool = True, progress: Callable[[str], None] | None = None,
                  corrections_dir: str | None = None) -> dict[str, Any]:
    """Run every case; returns ``{"cases": [...], "limits": {...}, "learning": {...}, "conditions": {...}}``.

    ``identified`` is required for the ``identified`` truth (else that truth is skipped).  ``constrained`` also
    runs, on the nominal truth, the constrained preview on the cases whose unconstrained shaped reference would
    ask more than the limits (rows with ``"variant": "constrained_ls"``).  ``corrections_dir``: store every
    learned correction there (:func:`~.ilc.save_correction`, one ``.npz`` per trajectory and truth).
    """
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    fs = printed.sample_rate
    ilc = ilc or ILCConfig(iterations=4 if quick else 10)
    preview_cfg = preview_cfg or PreviewConfig()
    truths = tuple(t for t in truths if t != "identified" or identified is not None)
    say("build the compensators (printed model)")
    models = {"printed": TrackingModel.build(printed, preview_cfg)}
    if "identified" in truths:
        say("build the compensators (identified model)")
        assert identified is not None   # "identified" was dropped from truths without it
        models["identified"] = TrackingModel.build(identified, preview_cfg)
    cases_out: list[dict[str, Any]] = []
    learning_out: dict[str, Any] = {}
    constrained_cfg = dataclasses.replace(preview_cfg, constrained=True)
    constrained_stage: PreviewStage | None = None
    for case in benchmark_cases(quick, printed.axes):
        r, n_lead = reference_with_lead_in(case, fs)
        mask = evaluation_window(case, r, n_lead, fs)
        shaped: dict[int, np.ndarray] = {}
        for truth in truths:
            m = models["identified" if truth == "identified" else "printed"]
            key = id(m)
            if key not in shaped:
                shaped[key] = m.shaped(r)
            yr = shaped[key]
            noise = NOISE_M if truth == "noise_100nm" else 0.0
            clean = _truth_plant(printed, truth, 0.0, 0)
            base = {"trajectory": case.trajectory, "size_um": case.size_um, "frequency_hz": case.frequency_hz,
                    "truth": truth, "window_samples": int(mask.sum())}
            u, y = m.open_loop(clean, r)
            cases_out.append({**base, "method": "open", **tracking_metrics(y, r, u, mask, fs)})
            u, y = m.drive(clean, r)
            cases_out.append({**base, "method": "cascade", **tracking_metrics(y, r, u, mask, fs)})
            u, y = m.drive(clean, yr)
            row: dict[str, Any] = {**base, "method": "preview", **tracking_metrics(y, r, u, mask, fs)}
            u_ask, _ = CascadeReplica(m.cfg, controller_matrices(m.cascade)).process(yr)
            row["asked_peak_voltage_v"] = float(np.abs(u_ask).max())
            cases_out.append(row)
            if (constrained and truth == "nominal" and not quick
                    and row["asked_peak_voltage_v"] > m.cfg.limits.voltage - preview_cfg.voltage_margin):
                if constrained_stage is None:
                    constrained_stage = PreviewStage(m.cfg, controller_matrices(m.cascade), constrained_cfg,
                                                     model=m.compensated)
                t0 = time.perf_counter()
                yr_c = m.shaped(r, constrained_stage)
                u, y = m.drive(clean, yr_c)
                cases_out.append({**base, "method": "preview", "variant": "constrained_ls",
                                  **tracking_metrics(y, r, u, mask, fs), "qp_solves": constrained_stage.qp_solves,
                                  "qp_unconverged": constrained_stage.qp_unconverged,
                                  "compute_s": time.perf_counter() - t0})
            # learning: trials on the truth with its sensor, then one sensorless trial
            trial = [0]

            def run_trial(delta: np.ndarray, m: TrackingModel = m, yr: np.ndarray = yr, truth: str = truth,
                          noise: float = noise) -> np.ndarray:
                trial[0] += 1
                plant = _truth_plant(printed, truth, noise, seed=trial[0])
                return m.drive(plant, yr + delta)[1]

            learner = IterativeLearning(m.compensated, ilc)
            res = learner.learn(run_trial, r)
            u, y = m.drive(clean, yr + res.correction)
            cases_out.append({**base, "method": "learning", **tracking_metrics(y, r, u, mask, fs),
                              "iterations": ilc.iterations, "learning": res.to_json()})
            learning_out[f"{case.label} / {truth}"] = res.to_json()
            if corrections_dir is not None:
                from pathlib import Path

                from .ilc import save_correction

                Path(corrections_dir).mkdir(parents=True, exist_ok=True)
                name = f"{case.trajectory}_{case.size_um:g}um_{case.frequency_hz:g}hz_{truth}.npz"
                cases_out[-1]["correction_file"] = str(save_correction(
                    Path(corrections_dir) / name, res.correction, fs,
                    {"trajectory": case.traj.to_dict(), "lead_in_s": LEAD_IN_S},
                    {"truth": truth, "model": "identified" if truth == "identified" else "printed"}))
            say(f"{case.label:<22} {truth:<12} " + "  ".join(
                f"{c['method']}{'*' if c.get('variant') else ''} {c['rms_error_um']:.4g}"
                for c in cases_out if c["truth"] == truth and c["trajectory"] == case.trajectory
                and c["size_um"] == case.size_um and c["frequency_hz"] == case.frequency_hz) + " µm RMS")
    limits = physical_limits(models, printed, preview_cfg, ilc, quick, say)
    return {"cases": cases_out, "limits": limits, "learning": learning_out,
            "conditions": {"sample_rate_hz": fs, "voltage_limit_v": printed.limits.voltage,
                           "slew_limit_v_per_s": printed.limits.slew, "preview": preview_cfg.to_dict(),
                           "learning": dataclasses.asdict(ilc), "lead_in_s": LEAD_IN_S, "noise_m": NOISE_M,
                           "quick": quick, "truths": list(truths),
                           "compute_s": time.perf_counter() - t_start}}


def physical_limits(models: dict[str, TrackingModel], printed: PiezoConfig, preview_cfg: PreviewConfig, ilc: ILCConfig,
                    quick: bool, say: Callable[[str], None]) -> dict[str, Any]:
    """Preview horizon needed (error vs horizon), the RHP zeros behind it, and the learning condition per truth."""
    m = models["printed"]
    fs = printed.sample_rate
    rhp_zeros: dict[str, list[list[float]]] = {}
    out: dict[str, Any] = {"g_l_rhp_zeros_rad_s": rhp_zeros, "kernel": m.preview.kernel.truncation}
    axes = printed.axes
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            z = printed.dynamics.G_L[i, j].zeros()
            rhp = z[z.real > 0]
            rhp_zeros[f"{a}{b}"] = [[float(v.real), float(v.imag)] for v in rhp]
    # horizon sweep on the 20 µm circle at 10 Hz (model = plant)
    case = next(c for c in benchmark_cases(True, axes) if c.frequency_hz == 10)   # the 20 µm circle (sine) at 10 Hz
    r, n_lead = reference_with_lead_in(case, fs)
    mask = evaluation_window(case, r, n_lead, fs)
    sweep = []
    for h in ((0.0, 0.005, 0.02) if quick else (0.0, 0.001, 0.0025, 0.005, 0.01, 0.02, 0.04)):
        pc = dataclasses.replace(preview_cfg, horizon_s=max(h, 1.0 / fs), constrained=False)
        st = PreviewStage(m.cfg, controller_matrices(m.cascade), pc, model=m.compensated)
        u, y = m.drive(Plant(m.cfg), m.shaped(r, st))
        sweep.append({"horizon_s": pc.horizon_s, **tracking_metrics(y, r, u, mask, fs)})
    out["horizon_sweep_circle20um_10hz"] = sweep
    # learning condition: model vs truth compensated responses (linear parts)
    f, T_model = m.compensated.frequency_response()
    conds = {"nominal": convergence_factor(T_model, T_model, f, ilc)}
    if "identified" in models:
        mi = models["identified"]
        fi, T_id = mi.compensated.frequency_response()
        # the truth's T seen through the identified compensator: printed G_L · identified C, identified creep/hyst
        truth_T = CompensatedModel.from_config(printed, controller_matrices(mi.cascade)).frequency_response()[1]
        conds["identified"] = convergence_factor(T_id, truth_T, fi, ilc)
    out["learning_condition"] = conds
    out["learning_violation"] = violation_demo(m, printed, ilc, r, mask, quick)
    return out


def violation_demo(m: TrackingModel, printed: PiezoConfig, ilc: ILCConfig, r: np.ndarray, mask: np.ndarray,
                   quick: bool, delay_s: float = 1e-3) -> dict[str, Any]:
    """The learning condition violated on purpose: a truth with an unmodelled 1 ms input delay (its phase error
    passes 60° at 1/(6·delay) ≈ 167 Hz, where ``|1 − γ·T̂⁻¹T| ≥ 1`` for γ = 1) and 100 nm sensor noise, learned
    with a Q too wide to cut it (4 kHz) — without the guard, with it — and with the default Q."""
    from ..models.effects import InputDelay

    fs = printed.sample_rate
    n_iter = 6 if quick else 15
    f, T_model = m.compensated.frequency_response()
    T_true = T_model * np.exp(-2j * np.pi * f * delay_s)[:, None, None]
    runs: dict[str, Any] = {}
    for label, cfg in (("wide_q_no_guard", dataclasses.replace(ilc, q_bandwidth_hz=4000.0, patience=10 ** 6)),
                       ("wide_q_guard", dataclasses.replace(ilc, q_bandwidth_hz=4000.0)),
                       ("default_q", ilc)):
        trial = [0]

        def run_trial(delta: np.ndarray, cfg: ILCConfig = cfg) -> np.ndarray:
            trial[0] += 1
            plant = Plant(printed, pre=[InputDelay(delay_s, 1.0 / fs, printed.n_axes)], noise_std=NOISE_M,
                          seed=trial[0])
            return m.drive(plant, m.shaped(r) + delta)[1]

        learner = IterativeLearning(m.compensated, cfg)
        res = learner.learn(run_trial, r, iterations=n_iter)
        # the last correction tried, not only the best one: divergence shows there
        runs[label] = {**res.to_json(), "condition": convergence_factor(T_model, T_true, f, cfg),
                       "q_bandwidth_hz_set": cfg.q_bandwidth_hz, "guard": cfg.patience < 10 ** 6}
    return {"truth": f"nominal + {delay_s * 1e3:g} ms input delay + 100 nm noise", "case": "circle 20 µm 10 Hz",
            "runs": runs}
