"""Independent withheld-effect benchmark of ``piezo-ff diagnose``: generate, diagnose through the CLI, score.

Each case: TRAIN and TEST records (``t,u_x,u_y,x,y`` CSV, SI units) of a truth plant made by ``truth.py`` (this
benchmark's own simulator; nominal model read only through the public config) with a withheld effect in a form the
candidates do not use, or none (nulls); diagnosed by ``python -m piezo_ff_ros diagnose --train A --test B --json
OUT``; scored on the JSON's ``verdict``, ``confidence`` and ``heldout.{before,after,noise_floor}_nrmse_percent``.
Out-of-family cases (``cases.TEMPLATES`` × seeds) and the in-family cases of ``bench/bench_diagnosis.py`` (the
project's own generator) are reported apart, and the tuning and held-out seed sets (``seeds.py``) apart.

    python bench/diagnosis/run.py                              # tuning split, all families, 1 job
    python bench/diagnosis/run.py --split all --jobs 2 --json out/diagbench.json
    python bench/diagnosis/run.py --quick --only null,input_delay --family out     # seconds per case
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.diagnosis import cases as C  # noqa: E402
from bench.diagnosis import seeds as S  # noqa: E402
from bench.diagnosis import truth  # noqa: E402

#: the issue's targets (out-of-family)
TARGETS = {"top1": 0.90, "null_fp": 0.05, "median_shrink": 0.60, "high_accuracy": 0.95}
CONFIDENCE_LEVELS = ("high", "medium", "low")


# ----------------------------------------------------------------------------------------------------------------
# Generation
# ----------------------------------------------------------------------------------------------------------------

def _write_csv(path: Path, t, u, y) -> None:
    data = np.column_stack([t, u, y])
    np.savetxt(path, data, delimiter=",", header="t,u_x,u_y,x,y", comments="",
               fmt=["%.10g", "%.9g", "%.9g", "%.8e", "%.8e"])


def records(case: C.Case):
    """TRAIN and TEST ``(t, u, y)`` of ``case`` and the truth-side figures of TEST (RMS of the withheld effect's
    contribution and of the noise, so that a reader sees which cases are subtle)."""
    from piezo_ff_ros.core.config import load_config

    cfg = load_config().with_sample_rate(case.fs)
    if case.family == "in":
        from bench.synthetic.in_family import NOISE_STD, make_runs

        train, test = make_runs(cfg, case.in_family, duration=case.duration, seed=case.seed)
        info = {"effect_rms_um": float("nan"), "noise_rms_um": NOISE_STD * 1e6, "effect_to_noise": float("nan")}
        return [(r.t, r.u, r.y) for r in (train, test)], info
    nom = truth.nominal_matrices(cfg)
    base = [int(case.seed), zlib.crc32(case.template.encode())]
    out, info = [], {}
    for k, kind in enumerate(("train", "test")):
        rng = np.random.default_rng(base + [1 + k])
        u = truth.excitation(kind, case.fs, case.duration, rng, amplitude=case.amplitude)
        y_true = truth.simulate(nom, case.effects, u)
        y = truth.add_noise(y_true, 1.0 / case.fs, case.noise, np.random.default_rng(base + [11 + k]))
        out.append((np.arange(len(u)) / case.fs, u, y))
        if kind == "test":
            d = y_true - truth.simulate(nom, [], u)
            d -= d.mean(axis=0)
            e = y - y_true
            info = {"effect_rms_um": float(np.sqrt(np.mean(d ** 2)) * 1e6),
                    "noise_rms_um": float(np.sqrt(np.mean((e - e.mean(axis=0)) ** 2)) * 1e6)}
            info["effect_to_noise"] = info["effect_rms_um"] / max(info["noise_rms_um"], 1e-12)
    return out, info


def generate(case: C.Case, outdir: Path) -> dict:
    """Write ``train.csv`` and ``test.csv`` of ``case`` into ``outdir``; return the truth-side figures."""
    outdir.mkdir(parents=True, exist_ok=True)
    runs, info = records(case)
    for (t, u, y), name in zip(runs, ("train", "test")):
        _write_csv(outdir / f"{name}.csv", t, u, y)
    return info


# ----------------------------------------------------------------------------------------------------------------
# One case: generate → CLI → row
# ----------------------------------------------------------------------------------------------------------------

def run_case(case: C.Case, workdir: str, timeout: float, keep: bool) -> dict:
    d = Path(workdir) / case.name.replace("/", "__").replace("@", "_")
    row = {k: v for k, v in asdict(case).items() if k not in ("in_family",)}
    t0 = time.perf_counter()
    try:
        row["truth"] = generate(case, d)
    except Exception as exc:  # noqa: BLE001 - a generator failure is reported in the row, not a crash of the run
        row.update(error=f"generation failed: {exc!r}", correct=False, verdict="error")
        return row
    row["generate_seconds"] = time.perf_counter() - t0
    out = d / "diagnosis.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "piezo_ff_ros", "diagnose", "--train", str(d / "train.csv"), "--test",
           str(d / "test.csv"), "--json", str(out), "--quiet"]
    t1 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=str(ROOT), env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        row.update(error=f"diagnose timed out after {timeout:.0f} s", correct=False, verdict="error")
        return row
    row["diagnose_seconds"] = time.perf_counter() - t1
    if p.returncode != 0 or not out.is_file():
        msg = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        row.update(error=f"diagnose exit {p.returncode}: {msg}", correct=False, verdict="error")
        return row
    res = json.loads(out.read_text())
    h = res["heldout"]
    row.update(verdict=res["verdict"], confidence=res.get("confidence"),
               before=float(h["before_nrmse_percent"]), after=float(h["after_nrmse_percent"]),
               noise=float(h.get("noise_floor_nrmse_percent", float("nan"))),
               stacked=float(h.get("stacked_after_nrmse_percent", float("nan"))),
               ranking=[r["effect"] for r in res.get("ranking", [])[:3]],
               stack=[s["effect"] for s in res.get("stack", [])])
    row["correct"] = row["verdict"] == case.expected
    row["shrink"] = 1.0 - row["after"] / row["before"] if row["before"] > 0 else float("nan")
    ex_b = row["before"] ** 2 - row["noise"] ** 2
    row["excess_shrink"] = (1.0 - max(row["after"] ** 2 - row["noise"] ** 2, 0.0) / ex_b) if ex_b > 0 else float("nan")
    if not keep:
        for f in d.iterdir():
            f.unlink()
        d.rmdir()
    return row


# ----------------------------------------------------------------------------------------------------------------
# Scoring
# ----------------------------------------------------------------------------------------------------------------

def _median(x):
    x = [v for v in x if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return float(np.median(x)) if x else float("nan")


def summarise(rows: list[dict]) -> dict:
    """Top-1 accuracy (effect cases), null false-positive rate, median held-out shrink, calibration table.

    Cases whose diagnosis failed or timed out (verdict ``error``) are counted apart, not in the rates."""
    errors = [r for r in rows if r.get("verdict") == "error"]
    rows = [r for r in rows if r.get("verdict") != "error"]
    eff = [r for r in rows if r["expected"] != "none"]
    nul = [r for r in rows if r["expected"] == "none"]
    ok = [r for r in eff if r.get("correct")]
    calib = {}
    for lvl in CONFIDENCE_LEVELS + ("other",):
        sel = [r for r in rows if (r.get("confidence") if r.get("confidence") in CONFIDENCE_LEVELS else "other")
               == lvl and r.get("verdict") != "error"]
        calib[lvl] = {"n": len(sel), "right": sum(bool(r.get("correct")) for r in sel),
                      "accuracy": (sum(bool(r.get("correct")) for r in sel) / len(sel)) if sel else float("nan")}
    per_effect = {}
    for r in eff:
        pe = per_effect.setdefault(r["expected"], {"n": 0, "right": 0, "verdicts": {}})
        pe["n"] += 1
        pe["right"] += bool(r.get("correct"))
        pe["verdicts"][r.get("verdict")] = pe["verdicts"].get(r.get("verdict"), 0) + 1
    return {
        "cases": len(rows), "effect_cases": len(eff), "null_cases": len(nul),
        "top1_accuracy": len(ok) / len(eff) if eff else float("nan"),
        "null_false_positive_rate": (sum(not r.get("correct") for r in nul) / len(nul)) if nul else float("nan"),
        "median_shrink_correct": _median([r.get("shrink") for r in ok]),
        "median_shrink_all_effects": _median([r.get("shrink", 0.0) if r.get("verdict") != "error" else None
                                              for r in eff]),
        "median_excess_shrink_correct": _median([r.get("excess_shrink") for r in ok]),
        "unexplained_verdicts": sum(r.get("verdict") == "unexplained" for r in rows),
        "errors": len(errors),
        "calibration": calib,
        "per_effect": per_effect,
        "misses": [f"{r['name']} -> {r.get('verdict')} ({r.get('confidence')})" for r in rows if not r.get("correct")],
        "error_cases": [f"{r['name']}: {r.get('error')}" for r in errors],
    }


def _fmt_pct(x):
    return "  n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:5.1f}"


def print_row(r: dict) -> None:
    tag = "OK " if r.get("correct") else "BAD"
    if r.get("verdict") == "error":
        print(f"{r['name']:44s} ERROR {r.get('error')}", flush=True)
        return
    tr = r.get("truth", {})
    snr = tr.get("effect_to_noise", float("nan"))
    print(f"{r['name']:44s} {r['fs']:7.0f} Hz {r['duration']:6.1f} s {r['noise_kind']:9.9s} eff/noise "
          f"{snr:6.1f}  exp {r['expected']:28.28s} got {r['verdict']:28.28s} {str(r.get('confidence')):6.6s} {tag} "
          f"{r['before']:7.3f}% -> {r['after']:7.3f}% (noise {r['noise']:.3f}%)  "
          f"[{r.get('diagnose_seconds', float('nan')):.0f} s]", flush=True)


def print_summary(label: str, s: dict, targets: bool) -> None:
    print(f"\n== {label}: {s['cases']} cases scored ({s['effect_cases']} effects, {s['null_cases']} nulls), "
          f"{s['errors']} failed or timed out (not scored)")
    t = TARGETS
    mark = lambda ok: ("  [meets target]" if ok else "  [BELOW target]") if targets else ""  # noqa: E731
    print(f"  top-1 accuracy          {_fmt_pct(s['top1_accuracy'])} %" +
          mark(s["top1_accuracy"] >= t["top1"]) + (f"   target >= {100 * t['top1']:.0f} %" if targets else ""))
    print(f"  null false positives    {_fmt_pct(s['null_false_positive_rate'])} %" +
          mark(s["null_false_positive_rate"] <= t["null_fp"]) +
          (f"   target <= {100 * t['null_fp']:.0f} %" if targets else ""))
    print(f"  median held-out shrink  {_fmt_pct(s['median_shrink_correct'])} % on correct verdicts" +
          mark(s["median_shrink_correct"] >= t["median_shrink"]) +
          (f"   target >= {100 * t['median_shrink']:.0f} %" if targets else "") +
          f";  {_fmt_pct(s['median_shrink_all_effects'])} % over all effect cases; "
          f"{_fmt_pct(s['median_excess_shrink_correct'])} % of the gap above noise")
    print(f"  'unexplained' verdicts  {s['unexplained_verdicts']}")
    print("  confidence calibration (all cases of this group; 'high' must be right >= 95 %):")
    for lvl, c in s["calibration"].items():
        if c["n"]:
            print(f"    {lvl:7s} {c['right']:3d}/{c['n']:<3d} right = {_fmt_pct(c['accuracy'])} %")
    print("  per expected verdict:")
    for k, v in sorted(s["per_effect"].items()):
        others = ", ".join(f"{vv}×{n}" for vv, n in sorted(v["verdicts"].items(), key=lambda kv: -kv[1])
                           if vv != k)
        print(f"    {k:30s} {v['right']:2d}/{v['n']:<2d}" + (f"   (got {others})" if others else ""))


# ----------------------------------------------------------------------------------------------------------------

def _append_row(path, row: dict) -> None:
    if path:
        with open(path, "a") as fh:
            fh.write(json.dumps(row, default=float) + "\n")


def build_cases(split: str, family: str, quick: bool, only) -> list[tuple[str, C.Case]]:
    out = []
    splits = ("tuning", "heldout") if split == "all" else (split,)
    for sp in splits:
        seeds = {"tuning": S.TUNING_SEEDS, "heldout": S.HELDOUT_SEEDS, "fresh": S.FRESH_HELDOUT_SEEDS,
                 "fresh2": S.FRESH2_HELDOUT_SEEDS, "fresh3": S.FRESH3_HELDOUT_SEEDS,
                 "fresh4": S.FRESH4_HELDOUT_SEEDS, "fresh5": S.FRESH5_HELDOUT_SEEDS,
                 "fresh6": S.FRESH6_HELDOUT_SEEDS}[sp]
        if family in ("out", "all"):
            out += [(sp, c) for c in C.make_cases(seeds, quick=quick, only=only)]
        if family in ("in", "all"):
            out += [(sp, c) for c in C.in_family_cases(S.IN_FAMILY_SEED[sp], quick=quick, only=only)]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=("tuning", "heldout", "fresh", "fresh2", "fresh3", "fresh4", "fresh5", "fresh6", "all"),
                    default="tuning",
                    help="seed set: the tuning one (default), the frozen held-out one (looked at since), the fresh "
                         "held-out one (frozen in session 3, looked at since), the second fresh held-out one "
                         "(frozen in session 4, looked at since), the third (frozen in session 6, looked at since), the fourth "
                         "(frozen in session 8, looked at since), the fifth (frozen in session 9, looked at since), the sixth (frozen in session 10), or "
                         "tuning + held-out")
    ap.add_argument("--family", choices=("out", "in", "all"), default="all",
                    help="out-of-family (this benchmark's truths), in-family (the old bench cases), or both")
    ap.add_argument("--jobs", type=int, default=1, help="cases diagnosed in parallel (default 1)")
    ap.add_argument("--json", metavar="OUT", help="write per-case rows and summaries")
    ap.add_argument("--quick", action="store_true", help="short records (smoke runs and tests)")
    ap.add_argument("--only", help="comma-separated case-name prefixes or expected verdicts (e.g. null,input_delay)")
    ap.add_argument("--keep", metavar="DIR", help="keep the generated CSVs and JSONs in DIR")
    ap.add_argument("--rows", metavar="FILE", help="also append each case's row to FILE (JSON lines) as it "
                                                  "finishes (a cut run keeps its rows)")
    ap.add_argument("--timeout", type=float, default=900.0, help="per-case diagnosis timeout [s]")
    ap.add_argument("--list", action="store_true", help="list the cases and their truth parameters, run nothing")
    a = ap.parse_args(argv)
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    only = [o.strip() for o in a.only.split(",") if o.strip()] if a.only else None
    todo = build_cases(a.split, a.family, a.quick, only)
    if not todo:
        print("no case selected", file=sys.stderr)
        return 2
    if a.list:
        for sp, c in todo:
            print(f"{sp:8s} {c.name:44s} {c.regime:5s} {c.fs:7.0f} Hz {c.duration:7.1f} s {c.noise_kind:10s} "
                  f"expect {c.expected:28s} {json.dumps(c.effects) if c.family == 'out' else ''}")
        return 0
    t0 = time.perf_counter()
    tmp = tempfile.TemporaryDirectory(prefix="diagbench_") if not a.keep else None
    workdir = a.keep or tmp.name
    rows = []
    print(f"{len(todo)} cases, {a.jobs} job(s); records in {workdir}", flush=True)
    try:
        if a.jobs == 1:
            for sp, c in todo:
                r = run_case(c, workdir, a.timeout, bool(a.keep))
                r["split"] = sp
                rows.append(r)
                print_row(r)
                _append_row(a.rows, r)
        else:
            with ProcessPoolExecutor(max_workers=a.jobs) as ex:
                futs = [(sp, ex.submit(run_case, c, workdir, a.timeout, bool(a.keep))) for sp, c in todo]
                for sp, f in futs:
                    r = f.result()
                    r["split"] = sp
                    rows.append(r)
                    print_row(r)
                    _append_row(a.rows, r)
    finally:
        if tmp is not None:
            tmp.cleanup()
    summaries = {}
    for sp in ("tuning", "heldout", "fresh", "fresh2", "fresh3", "fresh4", "fresh5", "fresh6"):
        for fam in ("out", "in"):
            sel = [r for r in rows if r["split"] == sp and r["family"] == fam]
            if sel:
                key = f"{sp}/{fam}"
                summaries[key] = summarise(sel)
                print_summary(f"{sp} split, {'out-of-family' if fam == 'out' else 'in-family'}", summaries[key],
                              targets=(fam == "out"))
    print(f"\n{len(rows)} cases in {time.perf_counter() - t0:.0f} s")
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps({"summaries": summaries, "rows": rows, "targets": TARGETS,
                                            "seeds": {"tuning": S.TUNING_SEEDS, "heldout": S.HELDOUT_SEEDS,
                                                      "fresh": S.FRESH_HELDOUT_SEEDS,
                                                      "fresh2": S.FRESH2_HELDOUT_SEEDS,
                                                      "fresh3": S.FRESH3_HELDOUT_SEEDS,
                                                      "fresh4": S.FRESH4_HELDOUT_SEEDS,
                                                      "fresh5": S.FRESH5_HELDOUT_SEEDS,
                                                      "fresh6": S.FRESH6_HELDOUT_SEEDS}},
                                           indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
