"""Replay analysis of a recorded run (the ``piezo-ff analyze`` engine).

Given a :class:`~piezo_ff_ros.core.recording.run.RunData` read from a recording of the topic contract, this module

- cuts it into the segments announced on the ``experiment`` topic;
- hands the complete segments to the shared paper evaluation (``evaluate(recorded)`` of
  :mod:`piezo_ff_ros.core.experiments`, the same code ``piezo-ff reproduce`` uses), so that the result has the same
  keys as ``reproduce --json``;
- adds, under the key ``"replay"``, what only a recording can tell: tracking errors (RMS and max per axis, per
  segment and overall), gaps / duplicates / missing blocks per topic, saturated voltage samples and the driver's
  diagnostic counters, plus warnings.

Runs without experiment markers (a user's own references) get the ``"replay"`` part only.
No ROS import.
"""
from __future__ import annotations

import math

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from . import metrics
from .recording.run import RunData
from .safety import at_limit
from .jsonable import JsonResult, jsonable
from .units import to_um

__all__ = ["find_evaluate", "segment_signals", "tracking_summary", "analyze_run", "plot_run", "format_report",
           "AnalysisResult", "ReplayReport"]

DEFAULT_VOLTAGE_LIMIT = 200.0  #: [V] when the recording does not say (core.config LimitsConfig default)


# the shared record type (a NamedTuple: also unpacks as (t, reference, u, y))
from .experiments import Recorded as _Recorded

#: the paper evaluation ``evaluate(recorded, ...)`` (:func:`~piezo_ff_ros.core.reproduce.evaluate`): a
#: :class:`~.jsonable.JsonResult` (its ``to_json()`` keys) or a plain mapping
Evaluate = Callable[..., Any]


@dataclass(frozen=True)
class ReplayReport(JsonResult):
    """What only a recording can tell (the ``"replay"`` key of ``analyze --json``).

    Attributes
    ----------
    source : str or None
        The recording.
    duration_s, samples, sample_rate : float, int, float or None
        Length [s], samples and rate [Hz] of the analysed span.
    axes : list of str
        Column names.
    tracking : dict or None
        Tracking errors over the whole run [m] (:func:`tracking_summary`; voltage-driven segments and the lead-in
        of tracking segments left out).
    segments : list of dict
        Per experiment segment: ``name, k0, k1, samples, complete, stages, input, tracking`` and, for a tracking
        experiment, ``tracking_from_s``: its error is read from then on (after the lead-in its experiment names).
    blocks : dict
        Per block topic: count, gaps, missing samples/blocks, duplicates, … (from ``read_run``).
    saturation : dict
        ``{limit_V, samples, fraction}``: voltage samples at the limit.
    diagnostics : dict
        ``{messages, counters}``: the driver's last numeric diagnostic values.
    truncated : bool
        The file ended early (a prefix was read).
    warnings : list of str
        What was skipped or doubtful.
    """

    source: str | None
    duration_s: float
    samples: int
    sample_rate: float | None
    axes: list[str]
    tracking: dict[str, Any] | None
    segments: list[dict[str, Any]]
    blocks: dict[str, dict[str, Any]]
    saturation: dict[str, float]
    diagnostics: dict[str, Any]
    truncated: bool
    warnings: list[str]


@dataclass(frozen=True)
class AnalysisResult(JsonResult):
    """Result of :func:`analyze_run`: the paper's tables (when the run has experiment segments) and the replay report.

    ``to_json()`` is ``analyze --json``: the keys of the paper evaluation at the top level (as ``reproduce
    --json``) plus ``"replay"``.

    Attributes
    ----------
    tables : JsonResult, mapping or None
        The paper evaluation's result (None: not evaluated).
    replay : ReplayReport
        Tracking, gaps, saturation, diagnostics and warnings of the recording.
    """

    tables: Any
    replay: ReplayReport

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``analyze --json``.

        Returns
        -------
        dict
            The evaluation's keys (none when not evaluated) and ``"replay"``.
        """
        out: dict[str, Any] = dict(jsonable(self.tables)) if self.tables is not None else {}
        out["replay"] = self.replay.to_json()
        return out


def find_evaluate() -> Evaluate | None:
    """The shared paper evaluation ``evaluate(recorded) -> dict`` if it is installed, else ``None``."""
    for mod_name in ("piezo_ff_ros.core.experiments", "piezo_ff_ros.core.reproduce"):
        try:
            mod = importlib.import_module(mod_name)
        except ImportError:
            continue
        fn = getattr(mod, "evaluate", None)
        if callable(fn):
            found: Evaluate = fn
            return found
    return None


def segment_signals(run: RunData, complete_only: bool = True) -> tuple[dict[str, _Recorded], list[str]]:
    """``{name: (t, reference, u, y)}`` for the run's experiment segments (t starts at 0 in each segment).

    Segments with gaps, cut off by the start/end of the recording, or without a reference are left out (listed
    in the returned warnings) when ``complete_only``.  A segment name seen twice gets a ``#2`` suffix.
    """
    recorded: dict[str, _Recorded] = {}
    warnings: list[str] = []
    for seg in run.meta.get("segments", []):
        name = seg["name"]
        a, b = seg["start"], seg["stop"]
        if b - a < 2:
            warnings.append(f"segment {name!r}: not in the recorded span; skipped")
            continue
        if complete_only and not seg.get("complete", True):
            warnings.append(f"segment {name!r}: incomplete (gap or cut by the recording's start/end); skipped")
            continue
        ref = run.reference[a:b] if run.reference is not None else None
        if ref is None and complete_only:
            warnings.append(f"segment {name!r}: no reference recorded; skipped")
            continue
        key, i = name, 2
        while key in recorded:
            key, i = f"{name}#{i}", i + 1
        t = run.t[a:b] - run.t[a]
        recorded[key] = _Recorded(t, ref, run.u[a:b], run.y[a:b])
    return recorded, warnings


def tracking_summary(reference: ArrayLike | None, y: ArrayLike) -> dict[str, Any] | None:
    """Tracking errors [m] over the rows where both signals are finite (``None`` if there are none).

    Parameters
    ----------
    reference : array [N, axes] or None
        The reference [m]; None gives None.
    y : array [N, axes]
        The displacement [m].

    Returns
    -------
    dict or None
        :func:`~piezo_ff_ros.core.metrics.tracking_errors` of the finite rows, plus ``samples``.
    """
    if reference is None:
        return None
    r, yy = np.asarray(reference, float), np.asarray(y, float)
    ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(yy), axis=1)
    if not ok.any():
        return None
    out = metrics.tracking_errors(r[ok], yy[ok]).to_json()
    out["samples"] = int(ok.sum())
    return out


def _lead_in_s(seg: Mapping[str, Any]) -> float:
    """Seconds at the start of a tracking segment left out of its error (its experiment's ``params.skip``; 0 for
    other segments)."""
    info = seg.get("info") or {}
    if info.get("metric") != "tracking":
        return 0.0
    try:
        skip = float((info.get("params") or {}).get("skip", 0.0))
    except (TypeError, ValueError):
        return 0.0
    return skip if np.isfinite(skip) and skip > 0 else 0.0


def _voltage_limit(run: RunData) -> float:
    md = run.meta.get("metadata", {})
    for key in ("voltage_limit", "limits.voltage"):
        if key in md:
            try:
                v = float(md[key])
            except (TypeError, ValueError):
                continue
            if math.isfinite(v) and v > 0:
                return v
    cfg_yaml = md.get("config_yaml")
    if cfg_yaml and isinstance(cfg_yaml, str):
        try:
            from .config.loader import safe_yaml

            limit = (safe_yaml(cfg_yaml, "metadata config_yaml") or {}).get("limits", {}).get("voltage")
            if limit is not None and math.isfinite(float(limit)) and float(limit) > 0:
                return float(limit)
        except Exception:  # a config we cannot parse (or a hostile one): fall back to the default limit
            pass
    return DEFAULT_VOLTAGE_LIMIT


def _driver_counters(diagnostics: Mapping[str, Any]) -> dict[str, float]:
    """Numeric diagnostic values (saturation, slew, dropped, late, rejected …), last value per status/key."""
    out = {}
    for name, st in diagnostics.get("status", {}).items():
        for key, value in st.get("values", {}).items():
            try:
                out[f"{name}/{key}"] = float(value)
            except (TypeError, ValueError):
                continue
    return out


#: a displacement beyond this [m] is no position of a piezo stage (a corrupt or hostile sample): left out
PLAUSIBLE_DISPLACEMENT_M = 1.0
#: a voltage beyond this [V] is no drive voltage (a corrupt sample): left out of everything but the saturation count
PLAUSIBLE_VOLTAGE_V = 1e6


def _implausible(a: np.ndarray | None, bound: float, length_rows: np.ndarray | None = None) -> np.ndarray:
    """Rows of ``a`` with a finite value beyond ``±bound`` (only where ``length_rows`` is True, when given)."""
    if a is None or not len(a):
        return np.zeros(0 if a is None else len(a), bool)
    with np.errstate(invalid="ignore"):
        bad: np.ndarray = np.any(np.isfinite(a) & (np.abs(a) > bound), axis=1)
    return bad if length_rows is None else np.asarray(bad & length_rows)


def _sanitised(run: RunData, warnings: list[str]) -> RunData:
    """``run`` with implausible samples (a reference or displacement beyond ±1 m, a voltage beyond ±1e6 V) set to
    NaN — missing, as a lost block is — and one warning per signal saying how many and where; the voltage's
    saturation count is taken before (such a sample is at the limit)."""
    from dataclasses import replace as _replace

    by_voltage = np.zeros(len(run), bool)   # voltage-driven segments: the reference is in volts there
    for seg in run.meta.get("segments", []):
        if (seg.get("info") or {}).get("input") == "voltage":
            by_voltage[seg["start"]:seg["stop"]] = True
    changes: dict[str, np.ndarray] = {}
    for name, arr, bound, unit, rows in (
            ("reference", run.reference, PLAUSIBLE_DISPLACEMENT_M, "m", ~by_voltage),
            ("reference", run.reference, PLAUSIBLE_VOLTAGE_V, "V", by_voltage),
            ("y", run.y, PLAUSIBLE_DISPLACEMENT_M, "m", None), ("u", run.u, PLAUSIBLE_VOLTAGE_V, "V", None)):
        if arr is None:
            continue
        arr = np.asarray(changes.get(name, arr), float)
        bad = _implausible(arr, bound, rows if len(rows if rows is not None else []) == len(arr) else None)
        if not bad.any():
            continue
        k = int(np.argmax(bad))
        worst = float(np.nanmax(np.abs(arr[bad])))
        warnings.append(f"{'displacement' if name == 'y' else 'voltage' if name == 'u' else name}: "
                        f"{int(bad.sum())} sample(s) beyond ±{bound:g} {unit} (first at sample {k}, up to "
                        f"{worst:.3g} {unit}): not a plausible value, left out as missing")
        fixed = arr.copy()
        fixed[bad] = np.nan
        changes[name] = fixed
    if not changes:
        return run
    return _replace(run, u=changes.get("u", run.u), y=changes.get("y", run.y),
                    reference=changes.get("reference", run.reference))


def analyze_run(run: RunData, evaluate: Evaluate | None = None) -> AnalysisResult:
    """Analyse a recorded run.

    Parameters
    ----------
    run
        From :func:`~piezo_ff_ros.core.recording.mcap_io.read_run` (its ``meta`` supplies segments, gaps, …).
    evaluate
        The paper evaluation ``evaluate({name: (t, reference, u, y)}) -> dict``; default
        :func:`find_evaluate`.  Called only when the run has complete experiment segments.

    Returns
    -------
    AnalysisResult
        ``tables``: the result of ``evaluate`` (as ``reproduce --json``: the paper's tables) or None; ``replay``:
        :class:`ReplayReport`.  ``to_json()`` gives ``analyze --json``.
    """
    meta = run.meta
    warnings = list(meta.get("warnings", []))
    limit = _voltage_limit(run)
    u_raw = np.asarray(run.u, float)
    finite_u = np.all(np.isfinite(u_raw), axis=1)
    saturated = at_limit(u_raw[finite_u], limit)   # the driver's saturated_samples rule: the two agree
    run = _sanitised(run, warnings)
    tables: Any = None
    recorded, seg_warn = segment_signals(run)
    warnings += seg_warn
    if recorded and evaluate is None:
        found = find_evaluate()
        if found is not None:   # the paper's experiments on the recording's axes; other segments (a
            # commissioning's characterisation runs) are the replay's only
            from .experiments import paper_experiments

            names = {e.name for e in paper_experiments(axes=tuple(run.axes))}
            others = [k for k in recorded if k not in names]
            recorded = {k: v for k, v in recorded.items() if k in names}
            if others and not recorded:
                warnings.append(f"no paper experiment among the segments ({len(others)} others): tables skipped")
            evaluate = lambda rec: found(rec, axes=tuple(run.axes))   # noqa: E731
    if recorded:
        if evaluate is None:
            warnings.append("paper evaluation (core.experiments.evaluate) not available: tables skipped")
        else:
            try:
                tables = evaluate(recorded)
            except ValueError as exc:
                warnings.append(f"paper evaluation failed on this recording: {exc}")
    elif meta.get("segments"):
        warnings.append("no complete experiment segment: paper tables skipped")

    segments = []
    # Segments driven by voltage (the paper's S0 experiments: the "reference" topic then carries volts) have no
    # displacement reference: no tracking error for them, and they are left out of the whole-run figure.
    length_ref = np.ones(len(run), bool)
    for seg in meta.get("segments", []):
        a, b = seg["start"], seg["stop"]
        by_voltage = (seg.get("info") or {}).get("input") == "voltage"
        if by_voltage:
            length_ref[a:b] = False
        # a tracking experiment (a circle) starts a radius away from the stage at rest: its error is read after
        # the lead-in the experiment names (``params.skip``: the paper reads the last revolution), as the circle tracking figures are
        skip = _lead_in_s(seg)
        lead = min(b - a, int(round(skip * run.sample_rate))) if skip else 0
        if lead and not by_voltage:
            length_ref[a:a + lead] = False
        ref = run.reference[a + lead:b] if run.reference is not None else None
        entry = {"name": seg["name"], "k0": seg["k0"], "k1": seg["k1"], "samples": int(b - a),
                 "complete": seg.get("complete", True), "stages": seg.get("stages"),
                 "input": "voltage" if by_voltage else "displacement",
                 "tracking": tracking_summary(ref, run.y[a + lead:b]) if b > a + lead and not by_voltage else None}
        if skip:
            entry["tracking_from_s"] = skip
        segments.append(entry)
    whole_ref = None
    if run.reference is not None:
        whole_ref = np.where(length_ref[:, None], run.reference, np.nan)

    diag = meta.get("diagnostics", {})
    blocks = {role: {k: v for k, v in info.items()} for role, info in meta.get("blocks", {}).items()}
    replay = ReplayReport(
        source=meta.get("source"),
        duration_s=len(run) / run.sample_rate if len(run) > 1 else 0.0,
        samples=len(run),
        sample_rate=meta.get("sample_rate", run.sample_rate if len(run) > 1 else None),
        axes=list(run.axes),
        tracking=tracking_summary(whole_ref, run.y),
        segments=segments,
        blocks=blocks,
        saturation={"limit_V": limit, "samples": saturated, "fraction": saturated / max(int(finite_u.sum()), 1)},
        diagnostics={"messages": diag.get("messages", 0), "counters": _driver_counters(diag)},
        truncated=bool(meta.get("truncated", False)),
        warnings=warnings,
    )
    return AnalysisResult(tables=tables, replay=replay)


def plot_run(run: RunData, out_dir: str | Path, max_points: int = 20000) -> list[Path]:
    """PNG plots (Agg): one per segment (or one for the whole run without markers) — reference and displacement
    per axis [µm] and the tracking error [µm] — and the voltages.  Returns the written paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    parts = [(s["name"], s["start"], s["stop"]) for s in run.meta.get("segments", []) if s["stop"] > s["start"]]
    if not parts:
        parts = [("run", 0, len(run))]
    written = []
    for i, (name, a, b) in enumerate(parts):
        step = max(1, (b - a) // max_points)
        sl = slice(a, b, step)
        t = run.t[sl]
        n_ax = len(run.axes)
        fig, axs = plt.subplots(3, n_ax, figsize=(5 * n_ax, 8), sharex=True, squeeze=False)
        for j, axis in enumerate(run.axes):
            ax = axs[0][j]
            if run.reference is not None:
                ax.plot(t, to_um(run.reference[sl, j]), "k--", lw=1, label="reference")
            ax.plot(t, to_um(run.y[sl, j]), lw=1, label="displacement")
            ax.set_ylabel(f"{axis} [µm]")
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
            if run.reference is not None and np.isfinite(run.reference[sl, j]).any():
                axs[1][j].plot(t, to_um(run.y[sl, j] - run.reference[sl, j]), lw=1, color="C3")
            else:   # an empty panel says why
                axs[1][j].text(0.5, 0.5, "no reference recorded here: no tracking error\n(the recording has no "
                               "`reference` blocks for this span)", ha="center", va="center",
                               transform=axs[1][j].transAxes, fontsize=9, color="0.3")
            axs[1][j].set_ylabel(f"error {axis} [µm]")
            axs[2][j].plot(t, run.u[sl, j], lw=1, color="C2")
            axs[2][j].set_ylabel(f"u{axis} [V]")
            axs[2][j].set_xlabel("t [s]")
        fig.suptitle(f"{name}  ({Path(str(run.meta.get('source', ''))).name})")
        fig.tight_layout()
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)
        path = out / f"{i:02d}_{safe}.png"
        fig.savefig(path, dpi=90, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written


def format_report(result: AnalysisResult | Mapping[str, Any]) -> str:
    """Human-readable summary of :func:`analyze_run`'s result (tracking in µm, counts).

    Parameters
    ----------
    result : AnalysisResult or mapping
        From :func:`analyze_run`, or its JSON.

    Returns
    -------
    str
        One line per block topic, saturation, diagnostics, tracking per segment, warnings.
    """
    if isinstance(result, AnalysisResult):
        result = result.to_json()
    rp = result["replay"]
    lines = [f"{rp['source']}: {rp['samples']} samples, {rp['duration_s']:.3f} s at {rp['sample_rate']:.0f} Hz, "
             f"axes {','.join(rp['axes'])}" + ("  [TRUNCATED file: prefix only]" if rp["truncated"] else "")]
    for role, b in rp["blocks"].items():
        lines.append(f"  {role:<12} {b['topic']:<20} {b['count']:>7} blocks  gaps {len(b['gaps'])} "
                     f"(missing {b['missing_samples']} samples ≈ {b['missing_blocks']} blocks)  "
                     f"duplicates {b['duplicates']}  malformed {b['malformed']}")
    sat = rp["saturation"]
    lines.append(f"  saturated voltage samples (|u| ≥ {sat['limit_V']:g} V): {sat['samples']}")
    if rp["diagnostics"]["messages"]:
        counters = ", ".join(f"{k}={v:g}" for k, v in rp["diagnostics"]["counters"].items())
        lines.append(f"  diagnostics: {rp['diagnostics']['messages']} messages; last counters: {counters or '-'}")

    def fmt(tr: Mapping[str, Any] | None) -> str:
        if not tr:
            return "n/a"
        rms = "/".join(f"{to_um(v):.4g}" for v in tr["rms"])
        mx = "/".join(f"{to_um(v):.4g}" for v in tr["max"])
        return f"RMS {rms} µm, max {mx} µm"

    lines.append(f"  tracking error (whole run, per axis): {fmt(rp['tracking'])}")
    if rp["segments"]:
        lines.append("  segments:")
        for s in rp["segments"]:
            flag = "" if s["complete"] else "  (incomplete)"
            if s.get("tracking_from_s"):
                flag = f"  (from t = {s['tracking_from_s']:g} s){flag}"
            lines.append(f"    {s['name']:<28} k0={s['k0']:<9} {s['samples']:>8} samples  {fmt(s['tracking'])}{flag}")
    for w in rp["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)
