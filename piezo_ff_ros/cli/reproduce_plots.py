"""PNG figures like the paper's Fig. 4, 6, 7, 10, 11, 14 and 15 from recorded experiments (matplotlib, Agg).

Grids follow the paper's layout: panel (a) x ← x, (b) x ← y, (c) y ← x, (d) y ← y (row = output axis,
column = driven axis).  Lengths in µm, time in s.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..core.units import UM

if TYPE_CHECKING:
    from ..core.experiments import Experiment

FIGURES = {
    "fig04_hysteresis_S0.png": ("hyst_S0_{a}", "loop", "Fig. 4 — hysteresis of S0 (200 V, 0.1 Hz)", "U_{a} [V]"),
    "fig06_hysteresis_SH.png": ("hyst_SH_{a}", "loop", "Fig. 6 — hysteresis compensated (S_H, 20 µm, 0.1 Hz)",
                                "{a}_h [µm]"),
    "fig07_creep_SH.png": ("creep_SH_{a}", "time", "Fig. 7 — creep of S_H (20 µm steps)", "t [s]"),
    "fig10_creep_SL.png": ("creep_SL_{a}", "time", "Fig. 10 — creep compensated (S_L)", "t [s]"),
    "fig11_steps_SL.png": ("step_SL_{a}", "step", "Fig. 11 — step responses of S_L (vibration)", "t [s]"),
    "fig14_steps_T.png": ("step_T_{a}", "step", "Fig. 14 — step responses of T (complete compensation)",
                          "t [s]"),
}


def write_plots(recorded: Mapping[str, tuple[Any, ...]], experiments: Sequence[Experiment], directory: str | Path,
                axes: Sequence[str] = ("x", "y")) -> list[Path]:
    """Write every figure whose experiments are in ``recorded``; return the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(directory)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    letters = "abcd"
    for fname, (pattern, kind, title, xlabel) in FIGURES.items():
        names = [pattern.format(a=a) for a in axes]
        if not all(n in recorded for n in names):
            continue
        fig, grid = plt.subplots(len(axes), len(axes), figsize=(9, 7), squeeze=False)
        for col, (a, name) in enumerate(zip(axes, names)):
            t, ref, u, y = recorded[name]
            t = np.asarray(t)
            for row, b in enumerate(axes):
                ax = grid[row][col]
                yb = np.asarray(y)[:, row] / UM
                if kind == "loop":
                    xin = np.asarray(ref)[:, col]
                    xin = xin if "hyst_S0" in name else xin / UM
                    ax.plot(xin, yb, lw=0.8)
                    ax.set_xlabel(xlabel.format(a=a))
                else:
                    sel = t <= 0.25 if kind == "step" else slice(None)
                    ax.plot(t[sel], yb[sel], lw=0.8, label="output")
                    ax.plot(t[sel], np.asarray(ref)[sel, row] / UM, "k--", lw=0.6, label="input")
                    ax.set_xlabel(xlabel.format(a=a))
                ax.set_ylabel(f"{b} [µm]")
                ax.set_title(f"({letters[row * len(axes) + col]}) {b} ← {a}", fontsize=9)
                ax.grid(True, lw=0.3)
        fig.suptitle(title)
        fig.tight_layout()
        path = out_dir / fname
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        written.append(path)

    circles = [e for e in experiments if e.metric == "tracking" and e.name in recorded]
    if circles:
        radii = sorted({e.params["radius"] for e in circles})
        fig, grid = plt.subplots(1, len(radii), figsize=(5 * len(radii), 5), squeeze=False)
        for ax, r in zip(grid[0], radii):
            for e in circles:
                if e.params["radius"] != r:
                    continue
                t, ref, u, y = recorded[e.name]
                sel = np.asarray(t) >= e.params.get("skip", 0.0)
                yy = np.asarray(y)[sel] / UM
                style = "-" if e.system == "T" else ":"
                ax.plot(yy[:, 0], yy[:, 1], style, lw=1.0,
                        label="complete compensation" if e.system == "T" else "no compensation")
            th = np.linspace(0, 2 * np.pi, 400)
            ax.plot(r / UM * np.sin(th), r / UM * np.cos(th), "k--", lw=0.7, label="reference")
            ax.set_aspect("equal")
            ax.set_xlabel("x [µm]")
            ax.set_ylabel("y [µm]")
            ax.set_title(f"radius {r / UM:g} µm")
            ax.grid(True, lw=0.3)
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        fig.suptitle("Fig. 15 — circular trajectory tracking (last revolution)")
        fig.tight_layout()
        path = out_dir / "fig15_circles.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written
