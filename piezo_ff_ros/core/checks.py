"""Sanity report on a positioner config: every transfer function's order, DC gain, poles, zeros, duplicated factors,
and the derived facts that decide whether the cascade can work (Dp/K invertibility, creep-compensator loop poles,
the provable DC bound on the H∞ optimum).  ``piezo-ff check [CONFIG]`` prints it."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .compensators.creep import creep_inverse_poles
from .config import PiezoConfig
from .lti import FactoredTF

__all__ = ["config_report", "format_config_report"]


def _tf_facts(tf: FactoredTF) -> dict[str, Any]:
    p = tf.cancelled().poles()
    z = tf.cancelled().zeros()
    wn = np.abs(p)
    zeta = np.where(wn > 0, -p.real / np.where(wn > 0, wn, 1.0), 1.0)
    return {
        "order": tf.order,
        "order_after_cancellation": tf.cancelled().order,
        "relative_degree": tf.relative_degree,
        "dc_gain": tf.dc_gain(),
        "duplicated_factors": [list(f) for f in tf.duplicated_factors()],
        "slowest_pole_rad_s": float(np.min(wn)) if len(p) else None,
        "fastest_pole_rad_s": float(np.max(wn)) if len(p) else None,
        "min_damping": float(np.min(zeta)) if len(p) else None,
        "stable": bool(np.all(p.real < 0)),
        "rhp_zeros": [complex(v) for v in z[z.real > 0]],
    }


def config_report(cfg: PiezoConfig) -> dict[str, Any]:
    """The sanity facts of ``cfg`` (see the module docstring), JSON-ready.

    Parameters
    ----------
    cfg : PiezoConfig
        The configuration to check.

    Returns
    -------
    dict
        ``name``, ``variant``, ``sample_rate``, per-entry facts of ``creep_Cr`` and ``dynamics_G_L``, and the
        ``hysteresis``, ``creep`` and ``dynamics`` summaries.
    """
    ax = cfg.axes
    out: dict[str, Any] = {"name": cfg.name, "variant": cfg.variant, "sample_rate": cfg.sample_rate,
                           "creep_Cr": {}, "dynamics_G_L": {}}
    for label, tfm in (("creep_Cr", cfg.creep.Cr), ("dynamics_G_L", cfg.dynamics.G_L)):
        for i, a in enumerate(ax):
            for j, b in enumerate(ax):
                if not tfm[i, j].is_zero():
                    out[label][f"{a}{b}"] = _tf_facts(tfm[i, j])
    Dp = np.array(cfg.hysteresis.Dp)
    K = np.array(cfg.creep.K)
    G0 = cfg.dynamics.G_L.dc_gain()
    p = creep_inverse_poles(cfg.creep, cfg.dt)
    out["hysteresis"] = {"Dp_condition": float(np.linalg.cond(Dp)), "generalized": cfg.hysteresis.generalized}
    out["creep"] = {"K_condition": float(np.linalg.cond(K)),
                    "K_plus_Cr_dc": (K + cfg.creep.Cr.dc_gain()).tolist(),
                    "compensator_max_pole_modulus": float(np.max(np.abs(p))) if len(p) else 0.0,
                    "compensator_stable": bool(np.all(np.abs(p) < 1.0))}
    out["dynamics"] = {"G_L_dc": G0.tolist(),
                       "hinf_gamma_lower_bound_dc": float(np.linalg.norm(np.linalg.inv(G0), 2)),
                       "total_order": int(sum(cfg.dynamics.G_L[i, j].order for i in range(len(ax)) for j in range(len(ax))))}
    return out


def format_config_report(rep: Mapping[str, Any]) -> str:
    """:func:`config_report` as printed lines (``piezo-ff check``).

    Parameters
    ----------
    rep : mapping
        A :func:`config_report` result.

    Returns
    -------
    str
        The report, one fact per line.
    """
    lines = [f"config {rep['name']} (variant {rep['variant']}), fs = {rep['sample_rate']:g} Hz"]
    for label in ("creep_Cr", "dynamics_G_L"):
        lines.append(f"  {label}:")
        for key, f in rep[label].items():
            dup = f" DUPLICATED factor(s) {f['duplicated_factors']} cancel" if f["duplicated_factors"] else ""
            rhp = f", {len(f['rhp_zeros'])} RHP zero(s)" if f["rhp_zeros"] else ""
            lines.append(f"    {key}: order {f['order']} (rel. degree {f['relative_degree']}), DC gain {f['dc_gain']:+.5g}, "
                         f"poles {f['slowest_pole_rad_s']:.3g}…{f['fastest_pole_rad_s']:.3g} rad/s, "
                         f"min damping {f['min_damping']:.2g}{rhp}{dup}")
    h, c, d = rep["hysteresis"], rep["creep"], rep["dynamics"]
    lines.append(f"  hysteresis: cond(Dp) = {h['Dp_condition']:.3g}, generalized = {h['generalized']}")
    lines.append(f"  creep: cond(K) = {c['K_condition']:.3g}, compensator loop max |z| = "
                 f"{c['compensator_max_pole_modulus']:.12f} ({'stable' if c['compensator_stable'] else 'UNSTABLE'})")
    lines.append(f"  dynamics: G_L(0) = {np.array2string(np.array(d['G_L_dc']), precision=5)}, total order {d['total_order']}, "
                 f"H∞ optimum ≥ ‖G_L(0)⁻¹‖ = {d['hinf_gamma_lower_bound_dc']:.4f}")
    return "\n".join(lines)
