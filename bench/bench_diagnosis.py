"""Withheld-effect benchmark of ``piezo-ff diagnose``.

Truth plants = the paper's nominal model + ONE hidden effect (each of the ten at a clear and a subtle magnitude)
+ 100 nm white sensor noise, plus four noise-only (null) cases.  TRAIN and TEST use different excitations
(``bench/synthetic/in_family.py``); the diagnoser sees only the runs and the nominal model.

Prints top-1 accuracy, the null false-positive rate, the median held-out gap shrink on correct verdicts, the
parameter recovery error on clear cases, and the runtime; then two cases with two hidden effects at once (is the
greedy stack right?), which are not part of the accuracy figure.  ``--speed`` also times one 10-minute 20 kHz run
(``--data``-style: split into 5 min fit + 5 min held out).

    cd /work/main && PYTHONPATH=. .venv/bin/python bench/bench_diagnosis.py            # ~3-5 min on 2 idle cores
    PYTHONPATH=. .venv/bin/python bench/bench_diagnosis.py --speed                      # + the 10-minute run
    PYTHONPATH=. .venv/bin/python bench/bench_diagnosis.py --only input_delay,null      # a subset
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose, json_ready  # noqa: E402
from piezo_ff_ros.core.models.effects import build_plant  # noqa: E402
from bench.synthetic.in_family import NOISE_STD, excitation, make_runs, truth_cases  # noqa: E402
from piezo_ff_ros.core.recording.run import RunData  # noqa: E402

#: the parameters whose recovery is scored (the others are nuisance or zero in the truth)
SCORED = {"hysteresis_asymmetry": ["Delta1"], "hysteresis_rate_dependence": ["alpha"],
          "creep_nonlinearity": ["gamma", "beta"], "thermal_drift": ["amplitudes", "time_constant"],
          "input_delay": ["delay"], "amplifier_slew_limit": ["rate"], "amplifier_saturation": ["limit"],
          "amplifier_bandwidth": ["cutoff"], "unmodelled_mode": ["freq", "damping", "gains"],
          "gain_mismatch": ["gains"]}


def param_error(effect: str, truth: dict, fitted: dict) -> float:
    """Largest relative error over the scored parameters (gains: of the deviation from 1)."""
    errs = []
    for k in SCORED[effect]:
        t = np.atleast_1d(np.asarray(truth[k], float))
        f = np.atleast_1d(np.asarray(fitted[k]["value"], float))
        if f.ndim == 3:  # modes with cross-coupled gains [mode][out][in]: the first mode's direct gains
            f = np.diag(f[0])
        elif f.ndim == 2:  # [mode][axis]
            f = f[0]
        if k in ("freq", "damping") and f.size > t.size:
            f = f[:t.size]
        if k == "gains" and effect == "gain_mismatch":
            t, f = t - 1.0, f - 1.0
        m = np.abs(t) > 0
        errs.extend((np.abs(f[m] - t[m]) / np.abs(t[m])).tolist())
    return float(max(errs)) if errs else 0.0


def run_cases(fs: float, duration: float, only: list[str] | None, verbose: bool):
    cfg = load_config().with_sample_rate(fs)
    rows = []
    for case in truth_cases():
        if only and not any(case["name"].startswith(o) for o in only):
            continue
        train, test = make_runs(cfg, case, duration=duration)
        t0 = time.perf_counter()
        res = diagnose(cfg, train, test, DiagnosisOptions(verbose=verbose))
        dt = time.perf_counter() - t0
        truth = case["effect"]
        v = res["verdict"]
        row = {"case": case["name"], "truth": truth, "level": case["level"], "verdict": v,
               "confidence": res["confidence"], "correct": v == truth, "seconds": dt,
               "before": res["heldout"]["before_nrmse_percent"], "after": res["heldout"]["after_nrmse_percent"],
               "noise": res["heldout"]["noise_floor_nrmse_percent"],
               "stack": [s["effect"] for s in res["stack"]]}
        if v == truth and v != "none":
            fitted = next(r for r in res["ranking"] if r["effect"] == v)["params"]
            row["param_error"] = param_error(truth, case["params"], fitted)
            row["fitted"] = {k: p["value"] for k, p in fitted.items()}
        rows.append(row)
        pe = f"  param err {100 * row['param_error']:.2g} %" if "param_error" in row else ""
        print(f"{case['name']:36s} -> {v:28s} {'OK ' if row['correct'] else 'BAD'} held-out {row['before']:7.3f} % "
              f"-> {row['after']:7.3f} % (noise {row['noise']:.3f} %){pe}  [{dt:.1f} s]", flush=True)
    return rows


def summarise(rows) -> dict:
    eff = [r for r in rows if r["truth"] != "none"]
    null = [r for r in rows if r["truth"] == "none"]
    correct = [r for r in eff if r["correct"]]
    shrink = [1 - r["after"] / r["before"] for r in correct]
    excess = [1 - max(r["after"] ** 2 - r["noise"] ** 2, 0) / max(r["before"] ** 2 - r["noise"] ** 2, 1e-12)
              for r in correct]
    clear_err = [r["param_error"] for r in correct if r["level"] == "clear"]
    subtle_err = [r["param_error"] for r in correct if r["level"] == "subtle"]
    s = {
        "cases": len(rows),
        "top1_accuracy": len(correct) / len(eff) if eff else float("nan"),
        "top1_accuracy_clear": np.mean([r["correct"] for r in eff if r["level"] == "clear"]) if eff else float("nan"),
        "top1_accuracy_subtle": np.mean([r["correct"] for r in eff if r["level"] == "subtle"]) if eff else
        float("nan"),
        "null_false_positive_rate": float(np.mean([not r["correct"] for r in null])) if null else float("nan"),
        "median_heldout_shrink": float(np.median(shrink)) if shrink else float("nan"),
        "median_excess_shrink": float(np.median(excess)) if excess else float("nan"),
        "clear_param_error_median": float(np.median(clear_err)) if clear_err else float("nan"),
        "clear_param_error_max": float(np.max(clear_err)) if clear_err else float("nan"),
        "clear_within_20_percent": float(np.mean(np.array(clear_err) <= 0.2)) if clear_err else float("nan"),
        "subtle_param_error_median": float(np.median(subtle_err)) if subtle_err else float("nan"),
        "seconds_median": float(np.median([r["seconds"] for r in rows])) if rows else float("nan"),
        "seconds_total": float(np.sum([r["seconds"] for r in rows])),
        "misses": [f"{r['case']} -> {r['verdict']}" for r in rows if not r["correct"]],
    }
    return s


def combined_runs(fs: float, duration: float) -> list[dict]:
    """Two hidden effects at once (not in the accuracy figure): the greedy stack should find both."""
    cfg = load_config().with_sample_rate(fs)
    combos = [[("input_delay", {"delay": 0.5e-3}), ("gain_mismatch", {"gains": [1.03, 0.98]})],
              [("hysteresis_asymmetry", {"Delta1": [0.003, 0.002], "Delta2": [0.0, 0.0]}),
               ("thermal_drift", {"amplitudes": [0.4e-6, -0.3e-6], "time_constant": 8.0})]]
    out = []
    for k, effects in enumerate(combos):
        runs = []
        for j, kind in enumerate(("train", "test")):
            u = excitation(kind, fs, duration, seed=50 + k + j)
            y = build_plant(cfg, effects, noise_std=NOISE_STD, seed=60 + k + j).process(u)
            runs.append(RunData(np.arange(len(u)) / fs, u, y, ("x", "y")))
        t0 = time.perf_counter()
        res = diagnose(cfg, runs[0], runs[1], DiagnosisOptions())
        found = [s["effect"] for s in res["stack"]]
        truth = [e for e, _ in effects]
        ok = sorted(found) == sorted(truth)
        h = res["heldout"]
        print(f"combined {'+'.join(truth):45s} -> stack {found}  {'OK' if ok else 'BAD'}  held-out "
              f"{h['before_nrmse_percent']:.3f} % -> {h['stacked_after_nrmse_percent']:.3f} % (noise "
              f"{h['noise_floor_nrmse_percent']:.3f} %)  [{time.perf_counter() - t0:.1f} s]", flush=True)
        out.append({"truth": truth, "stack": found, "ok": ok})
    return out


def speed_run(minutes: float = 10.0, fs: float = 20000.0) -> dict:
    """One long run at the paper's rate, hidden input delay, diagnosed as ``--data`` would (split 50/50)."""
    cfg = load_config().with_sample_rate(fs)
    dur = minutes * 60.0
    t0 = time.perf_counter()
    half = dur / 2
    u = np.concatenate([excitation("train", fs, half, seed=7), excitation("test", fs, half, seed=8)])
    plant = build_plant(cfg, [("input_delay", {"delay": 0.5e-3})], noise_std=NOISE_STD, seed=5)
    y = np.concatenate([plant.process(u[i:i + 2_000_000]) for i in range(0, len(u), 2_000_000)])
    run = RunData(np.arange(len(u)) / fs, u, y, ("x", "y"), meta={"source": "synthetic 10-minute run"})
    gen = time.perf_counter() - t0
    train, test = run.split(0.5)
    t1 = time.perf_counter()
    c1 = time.process_time()
    res = diagnose(cfg, train, test, DiagnosisOptions(verbose=True), test_history=train)
    secs = time.perf_counter() - t1
    cpu = time.process_time() - c1
    print(f"10-minute 20 kHz run ({len(u)} samples, generated in {gen:.1f} s): verdict {res['verdict']} "
          f"(delay {next(r for r in res['ranking'] if r['effect'] == 'input_delay')['params']['delay']['value']:.4g}"
          f" s, truth 5e-4 s), diagnosed in {secs:.1f} s wall-clock, {cpu:.1f} s CPU (all threads); target <= 20 s")
    return {"samples": len(u), "verdict": res["verdict"], "seconds": secs, "cpu_seconds": cpu}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fs", type=float, default=5000.0, help="sample rate of the benchmark runs [Hz]")
    ap.add_argument("--duration", type=float, default=20.0, help="length of each run [s]")
    ap.add_argument("--only", help="comma-separated case-name prefixes (e.g. input_delay,null)")
    ap.add_argument("--speed", action="store_true", help="also time a 10-minute 20 kHz run")
    ap.add_argument("--no-combined", action="store_true", help="skip the two-hidden-effects cases")
    ap.add_argument("--combined-only", action="store_true", help="run only the two-hidden-effects cases")
    ap.add_argument("--json", help="write the per-case rows and the summary")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    only = [o.strip() for o in a.only.split(",")] if a.only else None
    t0 = time.perf_counter()
    if a.combined_only:
        combined_runs(a.fs, a.duration)
        return 0
    rows = run_cases(a.fs, a.duration, only, a.verbose)
    s = summarise(rows)
    print()
    print(f"top-1 accuracy            {100 * s['top1_accuracy']:.0f} %  (clear {100 * s['top1_accuracy_clear']:.0f} %,"
          f" subtle {100 * s['top1_accuracy_subtle']:.0f} %)   target >= 90 %")
    print(f"null false-positive rate  {100 * s['null_false_positive_rate']:.0f} %   target <= 10 %")
    print(f"median held-out shrink    {100 * s['median_heldout_shrink']:.0f} % of the NRMSE "
          f"({100 * s['median_excess_shrink']:.0f} % of the gap above noise)   target >= 50 %")
    print(f"parameter error, clear    median {100 * s['clear_param_error_median']:.2g} %, max "
          f"{100 * s['clear_param_error_max']:.2g} %, within 20 %: {100 * s['clear_within_20_percent']:.0f} % of "
          f"cases  (subtle: median {100 * s['subtle_param_error_median']:.2g} %)")
    print(f"runtime                   median {s['seconds_median']:.1f} s per case, {s['seconds_total']:.0f} s "
          f"diagnosing, {time.perf_counter() - t0:.0f} s in all")
    if s["misses"]:
        print("misses: " + "; ".join(s["misses"]))
    out = {"summary": s, "rows": rows}
    if not a.no_combined and not only:
        out["combined"] = combined_runs(a.fs, a.duration)
    if a.speed:
        out["speed"] = speed_run()
    if a.json:
        Path(a.json).write_text(json.dumps(json_ready(out), indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
