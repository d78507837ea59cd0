"""``piezo-ff diagnose`` on measured data no one here wrote (``../shared/data``), issue 5.

1. dbo_piezo_micromanipulator (single axis, 200 Hz): a classical Bouc-Wen identified on the 1 Hz ``Model_Vi_Do``
   run (``core.identification.bouc_wen``, offset fitted, no delay), as a 1-axis config (no creep, a 1 kHz
   first-order G_L, i.e. the one-sample lag ZOH gives at 200 Hz); diagnosed with TRAIN = the model run, TEST = the
   held-out ``Test_Vi_Do_Di`` run.
2. fsm_cubespec_piezo (3×3, 6400 Hz): a *linear* model (``core.identification.dynamics``, order 6 per entry) trained
   on the 100 mV level; diagnosed on the 200 mV and the 300 mV level (TRAIN = one training realization of that level,
   TEST = one test realization), where the published linear model's error grows from 0.114 to 0.555/1.319 µm.

    cd /work/main && PYTHONPATH=. .venv/bin/python bench/diagnose_real_data.py [--out DIR]

Writes a report (Markdown + PNG) per case into DIR (default /tmp/diagnose_real_data) and prints the findings.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from piezo_ff_ros.core.config import (BoucWenConfig, CascadeConfig, CreepConfig, DynamicsConfig,  # noqa: E402
                                      HinfConfig, PiezoConfig)
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose, json_ready  # noqa: E402
from piezo_ff_ros.core.diagnosis.report import write_report  # noqa: E402
from piezo_ff_ros.core.lti import FactoredTF, TFMatrix  # noqa: E402
from piezo_ff_ros.core.recording.run import RunData  # noqa: E402


def _print(res, name):
    h = res["heldout"]
    print(f"== {name}: verdict {res['verdict']} ({res['confidence']}); held-out NRMSE {h['before_nrmse_percent']:.3g} % "
          f"-> {h['after_nrmse_percent']:.3g} % (stacked {h['stacked_after_nrmse_percent']:.3g} %, noise floor "
          f"{h['noise_floor_nrmse_percent']:.3g} %), {res['seconds']:.1f} s")
    print("   where: " + res["where"]["summary"])
    for r in res["ranking"][:4]:
        ps = {k: v["value"] for k, v in r["params"].items()}
        print(f"   {r['effect']:28s} {r['heldout_before_nrmse_percent']:7.3f} % -> {r['heldout_after_nrmse_percent']:7.3f} %"
              f"{' accepted' if r['accepted'] else ''}  {ps}")
    print("   stack: " + ", ".join(f"{s['effect']} ({s['heldout_nrmse_percent']:.3g} %)" for s in res["stack"]))


def dbo_case(out: Path) -> dict:
    from piezo_ff_ros.core.datasets import load_dbo
    from piezo_ff_ros.core.identification.bouc_wen import identify_bouc_wen

    d = load_dbo()
    fit = identify_bouc_wen([d.model], [d.test], fit_offset=True, delay=0, skip=2.0)
    c = fit.config
    w = 2 * math.pi * 1000.0
    cfg = PiezoConfig.from_dict({
        "name": "dbo_bw_identified", "axes": ["x"], "sample_rate": 200.0, "units": {"length": "m"},
        "hysteresis": {"Dp": c.Dp, "A": c.A, "B": c.B, "Gamma": c.Gamma},
        "creep": {"K": [[1.0]], "Cr": {}}, "dynamics": {"G_L": {"xx": {"k": w, "num": [], "den": [[1, w]]}}},
        "vibration": {"W2": [1.0]}, "cascade": {"vibration": False}})
    print(f"dbo: classical Bouc-Wen identified on Model_Vi_Do: fit {fit.fit_train[0]:.1f} % (train), "
          f"{fit.fit_validation[0]:.1f} % (held-out test run)")
    res = diagnose(cfg, d.model, d.test, DiagnosisOptions())
    _print(res, "dbo_piezo_micromanipulator")
    write_report(res, out / "dbo")
    (out / "dbo" / "diagnosis.json").write_text(json.dumps(json_ready(res), indent=1))
    return res


def _linear_config(G: TFMatrix, axes, fs: float) -> PiezoConfig:
    n = len(axes)
    s = 1e-6  # Dp = 1 µm/V: the hysteresis stage is a pure gain (A = B = Γ = 0), G_L carries the rest
    eye = tuple(tuple(s if i == j else 0.0 for j in range(n)) for i in range(n))
    zero = tuple(tuple(0.0 for _ in range(n)) for _ in range(n))
    rows = [[G[i, j].scaled(1.0 / s) for j in range(n)] for i in range(n)]
    return PiezoConfig(name="fsm_linear_100mV", axes=tuple(axes), sample_rate=fs,
                       hysteresis=BoucWenConfig(Dp=eye, A=zero, B=zero, Gamma=zero),
                       creep=CreepConfig(K=tuple(tuple(1.0 if i == j else 0.0 for j in range(n)) for i in range(n)),
                                         Cr=TFMatrix.from_nested([[FactoredTF(0.0)] * n for _ in range(n)])),
                       dynamics=DynamicsConfig(TFMatrix.from_nested(rows)),
                       vibration=HinfConfig(W2=(1.0,) * n), cascade=CascadeConfig(vibration=False)).validate()


def fsm_cases(out: Path) -> dict:
    from piezo_ff_ros.core.datasets import load_fsm
    from piezo_ff_ros.core.identification.dynamics import identify_dynamics

    def asref(r):
        return RunData(r.t, r.u, r.y, r.axes, reference=r.u, meta=dict(r.meta))

    L100 = load_fsm(100)
    t0 = time.perf_counter()
    fit = identify_dynamics([asref(r) for r in L100.runs("train")[:2]], [asref(L100.runs("test")[0])], order=6)
    axes = L100.runs("train")[0].axes
    cfg = _linear_config(fit.config.G_L, axes, L100.runs("train")[0].sample_rate)
    print(f"fsm: linear model (order 6 per entry) identified at 100 mV in {time.perf_counter() - t0:.0f} s; "
          f"held-out fit at 100 mV {fit.fit_validation}")
    results = {}
    for level in (100, 200, 300):
        Lv = load_fsm(level)
        train, test = Lv.runs("train")[0], Lv.runs("test")[0]
        res = diagnose(cfg, train, test, DiagnosisOptions())
        rms = math.sqrt(float(np.mean((res["_arrays"]["test"].y - res["_arrays"]["y_test_nom"]
                                       - (res["_arrays"]["test"].y - res["_arrays"]["y_test_nom"]).mean(0)) ** 2)))
        print(f"fsm {level} mV: linear-100mV model held-out RMS error {rms * 1e6:.3f} µm "
              f"(published BLA trained at 100 mV: 0.114/0.555/1.319 µm at 100/200/300 mV)")
        _print(res, f"fsm_cubespec_piezo {level} mV")
        write_report(res, out / f"fsm_{level}mV")
        (out / f"fsm_{level}mV" / "diagnosis.json").write_text(json.dumps(json_ready(res), indent=1))
        results[level] = res
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/diagnose_real_data")
    ap.add_argument("--only", choices=["dbo", "fsm"])
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.only in (None, "dbo"):
        dbo_case(out)
    if a.only in (None, "fsm"):
        fsm_cases(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
