"""Run the clean-room benchmark of ``piezo-ff diagnose``: draw a split, write the cases, diagnose each through the CLI.

Only the public CLI is used (``python -m piezo_ff_ros diagnose --train --test --json``) and only these keys of its
JSON are read: ``verdict``, ``confidence``, ``heldout.before_nrmse_percent``, ``heldout.after_nrmse_percent``,
``heldout.noise_floor_nrmse_percent``.

Examples (from the repository root, with PYTHONPATH=$PWD so the tree's package is the one diagnosed)::

    nice -n 10 .venv/bin/python bench/cleanroom/run.py --split tuning --quick --jobs 1 --json tuning.json
    .venv/bin/python bench/cleanroom/run.py --split tuning --only input_delay,none --quick --keep /tmp/cases
    .venv/bin/python bench/cleanroom/run.py --split heldout --json heldout.json        # the integrator, once
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import truth  # noqa: E402

# split name -> (split seed, cases per effect class, null cases).  Case seeds are split_seed * 10000 + index, so
# the held-out split never shares a case seed with the tuning split.
SPLITS = {
    "tuning": (1, 2, 4),
    "heldout": (2, 3, 6),
}


def draw_split(split_seed, per_class, nulls):
    """The case list of a split: (case seed, class, form), forms cycled in a seed-dependent order per class."""
    import numpy as np

    rng = np.random.default_rng(split_seed)
    cases = []
    for cls in truth.EFFECT_CLASSES:
        forms = list(rng.permutation(truth.FORMS[cls]))
        for i in range(per_class):
            cases.append((split_seed * 10000 + len(cases), cls, str(forms[i % len(forms)])))
    for _ in range(nulls):
        cases.append((split_seed * 10000 + len(cases), "none", "none"))
    return cases


def run_case(seed, cls, form, *, quick, workdir, python, timeout, sampler="point"):
    t0 = time.time()
    case = truth.make_case(seed, cls, form, quick=quick, sampler=sampler)
    d = truth.write_case(case, Path(workdir) / f"{cls}__{form}__{seed}")
    gen_s = time.time() - t0
    out = d / "out.json"
    cmd = [python, "-m", "piezo_ff_ros", "diagnose", "--train", str(d / "train.csv"), "--test", str(d / "test.csv"),
           "--json", str(out), "--quiet"]
    t1 = time.time()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=os.getcwd())
    cli_s = time.time() - t1
    label = case["label"]
    row = {
        "case": label["case"], "expected": cls, "form": form, "fs_Hz": label["fs_Hz"],
        "effect_to_noise": label["effect_to_noise"], "effect_percent_of_signal": label["effect_percent_of_signal"],
        "noise": label["noise"]["kind"], "gen_s": round(gen_s, 1), "cli_s": round(cli_s, 1), "dir": str(d),
    }
    if proc.returncode != 0 or not out.exists():
        row.update(verdict="ERROR", confidence=None, before=None, after=None, floor=None,
                   error=(proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"])
        return row
    res = json.loads(out.read_text())
    held = res.get("heldout") or {}
    row.update(verdict=res.get("verdict"), confidence=res.get("confidence"),
               before=held.get("before_nrmse_percent"), after=held.get("after_nrmse_percent"),
               floor=held.get("noise_floor_nrmse_percent"))
    return row


def shrink(row):
    if row.get("before") and row.get("after") is not None and row["before"] > 0:
        return 1.0 - row["after"] / row["before"]
    return None


def summarise(rows):
    eff = [r for r in rows if r["expected"] != "none"]
    nul = [r for r in rows if r["expected"] == "none"]
    correct = [r for r in eff if r["verdict"] == r["expected"]]
    shrinks = [s for s in (shrink(r) for r in correct) if s is not None]
    per_class = {}
    for r in eff:
        c = per_class.setdefault(r["expected"], [0, 0])
        c[1] += 1
        c[0] += r["verdict"] == r["expected"]
    return {
        "effect_cases": len(eff), "top1_correct": len(correct),
        "top1_accuracy": len(correct) / len(eff) if eff else None,
        "null_cases": len(nul), "null_false_positives": sum(r["verdict"] != "none" for r in nul),
        "null_false_positive_rate": (sum(r["verdict"] != "none" for r in nul) / len(nul)) if nul else None,
        "median_shrink_on_correct": statistics.median(shrinks) if shrinks else None,
        "errors": sum(r["verdict"] == "ERROR" for r in rows),
        "per_class": {k: f"{v[0]}/{v[1]}" for k, v in per_class.items()},
    }


def fmt(x, spec):
    return format(x, spec) if isinstance(x, (int, float)) else "-"


def print_row(r, file=sys.stdout):
    ok = "none" if r["expected"] == "none" else ("OK" if r["verdict"] == r["expected"] else "miss")
    if r["expected"] == "none":
        ok = "OK" if r["verdict"] == "none" else "FP"
    s = shrink(r)
    print(f"| {r['case']} | {r['fs_Hz']:.0f} | {fmt(r['effect_percent_of_signal'], '.2f')} | "
          f"{fmt(r['effect_to_noise'], '.1f')} | {r['verdict']} | {r['confidence']} | {fmt(r['before'], '.3g')} | "
          f"{fmt(r['after'], '.3g')} | {fmt(r['floor'], '.3g')} | {fmt(s * 100 if s is not None else None, '.0f')} | "
          f"{ok} | {r['cli_s']} |", file=file, flush=True)


HEADER = ("| case | fs Hz | effect % of signal | effect/noise RMS | verdict | confidence | before % | after % | "
          "floor % | shrink % | | CLI s |\n|---|---|---|---|---|---|---|---|---|---|---|---|")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", choices=sorted(SPLITS), default="tuning")
    ap.add_argument("--seed", type=int, help="split seed (overrides the split's); case seeds are seed*10000+i")
    ap.add_argument("--per-class", type=int, help="cases per effect class (default: the split's)")
    ap.add_argument("--nulls", type=int, help="null cases (default: the split's)")
    ap.add_argument("--only", help="comma-separated classes (or 'none') or substrings of case ids")
    ap.add_argument("--quick", action="store_true", help="half-length records")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", help="write rows + summary here")
    ap.add_argument("--keep", help="write the cases into this directory and keep them")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per CLI call")
    ap.add_argument("--sampler", choices=truth.SAMPLERS, default="point",
                    help="ADC model: ideal sample-and-hold (default) or zero-phase anti-alias low-pass + decimation")
    ap.add_argument("--list", action="store_true", help="print the case list and exit")
    a = ap.parse_args(argv)
    seed, per_class, nulls = SPLITS[a.split]
    seed = a.seed if a.seed is not None else seed
    per_class = a.per_class if a.per_class is not None else per_class
    nulls = a.nulls if a.nulls is not None else nulls
    cases = draw_split(seed, per_class, nulls)
    if a.only:
        keys = [k.strip() for k in a.only.split(",") if k.strip()]
        cases = [c for c in cases if any(k == c[1] or k in f"{c[1]}/{c[2]}@{c[0]}" for k in keys)]
    if a.list:
        for c in cases:
            print(f"{c[1]}/{c[2]}@{c[0]}")
        return 0
    workdir = a.keep or tempfile.mkdtemp(prefix="cleanroom_")
    Path(workdir).mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    print(f"split={a.split} seed={seed} cases={len(cases)} quick={a.quick} sampler={a.sampler} "
          f"generator={truth.GENERATOR_VERSION} workdir={workdir}", flush=True)
    print(HEADER, flush=True)
    rows = []
    with cf.ThreadPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        futs = {ex.submit(run_case, s, c, f, quick=a.quick, workdir=workdir, python=sys.executable,
                          timeout=a.timeout, sampler=a.sampler): (s, c, f) for s, c, f in cases}
        for fut in cf.as_completed(futs):
            s, c, f = futs[fut]
            try:
                r = fut.result()
            except Exception as e:  # a case that cannot be generated or times out is a row, not a crash
                r = {"case": f"{c}/{f}@{s}", "expected": c, "form": f, "fs_Hz": float("nan"), "verdict": "ERROR",
                     "confidence": None, "before": None, "after": None, "floor": None, "effect_to_noise": None,
                     "effect_percent_of_signal": None, "cli_s": None, "error": [repr(e)]}
            rows.append(r)
            print_row(r)
    rows.sort(key=lambda r: r["case"])
    summ = summarise(rows)
    summ["wall_s"] = round(time.time() - t0, 1)
    print()
    print(f"top-1 on effect cases: {summ['top1_correct']}/{summ['effect_cases']}"
          f" = {fmt(summ['top1_accuracy'] and summ['top1_accuracy'] * 100, '.0f')} %")
    print(f"null false positives: {summ['null_false_positives']}/{summ['null_cases']}")
    ms = summ["median_shrink_on_correct"]
    print(f"median held-out shrink 1 - after/before on correct verdicts: {fmt(ms and ms * 100, '.1f')} %")
    print(f"per class: {summ['per_class']}")
    print(f"errors: {summ['errors']}; wall {summ['wall_s']} s")
    if a.json:
        Path(a.json).write_text(json.dumps({"split": a.split, "seed": seed, "quick": a.quick, "sampler": a.sampler,
                                            "generator": truth.GENERATOR_VERSION, "rows": rows,
                                            "summary": summ}, indent=1))
    if not a.keep:
        import shutil
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
