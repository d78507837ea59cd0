"""Figures of ``piezo-ff track``: one comparison plot (RMS error per case, method, truth) and the limits."""
from __future__ import annotations

from pathlib import Path

import numpy as np

METHOD_COLOURS = {"open": "#999999", "cascade": "#d62728", "preview": "#1f77b4", "learning": "#2ca02c"}


def plot_all(result: dict, out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    cases = [c for c in result["cases"] if not c.get("variant")]
    truths = list(dict.fromkeys(c["truth"] for c in cases))
    labels = list(dict.fromkeys(f"{c['trajectory']} {c['size_um']:g}µm {c['frequency_hz']:g}Hz" for c in cases))
    fig, axes = plt.subplots(len(truths), 1, figsize=(12, 2.6 * len(truths) + 0.6), sharex=True, squeeze=False)
    width = 0.2
    for ax, truth in zip(axes[:, 0], truths):
        for mi, m in enumerate(METHOD_COLOURS):
            vals = []
            for lab in labels:
                hit = [c for c in cases if c["truth"] == truth and c["method"] == m
                       and f"{c['trajectory']} {c['size_um']:g}µm {c['frequency_hz']:g}Hz" == lab]
                vals.append(hit[0]["rms_error_um"] if hit else np.nan)
            ax.bar(np.arange(len(labels)) + (mi - 1.5) * width, vals, width, label=m, color=METHOD_COLOURS[m])
        ax.set_yscale("log")
        ax.set_ylabel("RMS error [µm]")
        ax.set_title(f"truth: {truth}", fontsize=9, loc="left")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[-1, 0].set_xticks(np.arange(len(labels)))
    axes[-1, 0].set_xticklabels(labels, rotation=30, ha="right", fontsize=8)
    fig.suptitle("piezo-ff track: RMS tracking error (log scale), ±200 V amplifier")
    # the legend in a strip of its own under the title: inside a panel it covered bars
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, ncol=len(names), fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.955),
               frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    p1 = out_dir / "tracking.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    lim = result["limits"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 3.8))
    sw = lim["horizon_sweep_circle20um_10hz"]
    a1.loglog([s["horizon_s"] * 1e3 for s in sw], [s["rms_error_um"] for s in sw], "o-")
    a1.set_xlabel("preview horizon [ms]")
    a1.set_ylabel("RMS error [µm]")
    a1.set_title("circle 20 µm 10 Hz, model = plant", fontsize=9)
    a1.grid(True, which="both", alpha=0.3)
    for name, run in lim["learning_violation"]["runs"].items():
        a2.semilogy(run["rms_history_um"], "o-", label=f"{name} (ρ = {run['condition']['rho']:.2g})")
    a2.set_xlabel("trial")
    a2.set_ylabel("RMS error [µm]")
    a2.set_title(lim["learning_violation"]["truth"], fontsize=9)
    a2.grid(True, which="both", alpha=0.3)
    # beside the panel, not over the histories it names
    a2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    p2 = out_dir / "limits.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    return [p1, p2]
