"""The independent diagnosis benchmark (bench/diagnosis): its truth generator and a quick end-to-end run.

The generator must be right on its own terms (a null case is the nominal plant + noise, the exact ZOH and the
delayed ZOH agree with references it did not write, every withheld effect changes the output) and must stay apart
from the code it judges (no import of the candidates or of the package's plant models).
"""
from __future__ import annotations

import ast
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

ROOT = Path(__file__).resolve().parents[1]
if not (ROOT / "bench" / "diagnosis" / "truth.py").is_file():  # an installed/colcon copy without the bench tree
    pytest.skip("bench/diagnosis is not part of this copy of the package", allow_module_level=True)
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.diagnosis import cases as C  # noqa: E402
from bench.diagnosis import run as R  # noqa: E402
from bench.diagnosis import seeds as S  # noqa: E402
from bench.diagnosis import truth  # noqa: E402
from piezo_ff_ros.core.config import load_config  # noqa: E402


def test_truth_is_written_apart_from_the_judged_code():
    """truth.py and cases.py import neither the candidates/effects nor the package's plant models."""
    for name in ("truth.py", "cases.py"):
        tree = ast.parse((ROOT / "bench" / "diagnosis" / name).read_text())
        mods = []
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                mods += [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                mods.append(node.module or "")
        bad = [m for m in mods if m.startswith("piezo_ff_ros") and m != "piezo_ff_ros.core.config"
               and not m.endswith("diagnosis.synthetic")]
        assert not bad, f"{name} imports {bad}"
        if name == "truth.py":
            assert not any(m.startswith("piezo_ff_ros") for m in mods)


@pytest.mark.parametrize("fs", [200.0, 1000.0, 20000.0])
def test_null_truth_is_the_nominal_plant(fs):
    """With no effect the independent simulator gives the package's nominal plant (a different implementation).

    Both integrate the Bouc-Wen along the voltage path, in different sub-steps (the package's κ ≤ 1e-3, the
    truth's ≤ 0.01 V), so they agree to the package's stated accuracy (~0.01 % of the output), not to rounding;
    one explicit step per sample (the old model) is 40 % off at 200 Hz and fails this.
    """
    from piezo_ff_ros.core.models.plant import Plant  # the reference, used only to check the generator

    cfg = load_config().with_sample_rate(fs)
    u = truth.excitation("test", fs, 40.0 if fs < 1000 else 2.0, np.random.default_rng(3))
    y = truth.simulate(truth.nominal_matrices(cfg), [], u)
    y_ref = Plant(cfg).process(u)
    assert np.max(np.abs(y - y_ref)) <= 5e-4 * np.max(np.abs(y_ref))


def test_null_case_records_are_nominal_plus_the_stated_noise(tmp_path):
    from piezo_ff_ros.core.models.plant import Plant
    from piezo_ff_ros.core.recording import load_run

    case = next(c for c in C.make_cases([S.TUNING_SEEDS[0]], quick=True, only=["null/fast_white"]))
    R.generate(case, tmp_path)
    run = load_run(tmp_path / "test.csv")
    cfg = load_config().with_sample_rate(case.fs)
    e = run.y - Plant(cfg).process(run.u)
    expected = math.hypot(case.noise["white"], case.noise["quantum"] / math.sqrt(12))
    assert abs(e.std() / expected - 1) < 0.1
    assert abs(e.mean()) < 3 * expected / math.sqrt(e.size) + 1e-12
    steps = np.round(run.y / case.noise["quantum"])
    assert np.allclose(run.y, steps * case.noise["quantum"], atol=1e-15)


def test_modal_zoh_matches_scipy_cont2discrete():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = 2 * np.pi * rng.uniform(5, 3000)
        z = rng.uniform(0.01, 0.9)
        p = 2 * np.pi * rng.uniform(1, 2000)
        num = [rng.normal(), rng.normal() * w, w * w * p]
        den = np.polymul([1, 2 * z * w, w * w], [1, p])
        dt = 1.0 / rng.choice([200.0, 1000.0, 5000.0, 20000.0, 100000.0])
        u = rng.standard_normal(400)
        y = truth.lti_siso(truth.tf_from_poly(num, den), dt, u)
        Ad, Bd, Cd, Dd, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, method="zoh")
        y_ref = signal.dlsim((Ad, Bd, Cd, Dd, dt), u)[1].ravel()
        assert np.max(np.abs(y - y_ref)) <= 1e-9 * max(np.max(np.abs(y_ref)), 1e-300)


def test_delayed_zoh_is_the_delayed_staircase_response():
    """A held input acting fT late: the modified ZOH equals a fine-grid exact ZOH of the shifted staircase."""
    rng = np.random.default_rng(1)
    num, den = [3e3, 4e6], [1.0, 300.0, 4e6]
    m = truth.tf_from_poly(num, den)
    dt, up, frac = 1e-3, 40, 0.35
    u = rng.standard_normal(200)
    y = truth.lti_siso(m, dt, u, delay_samples=1 + frac)
    fine = np.concatenate([np.zeros(int(round((1 + frac) * up))), np.repeat(u, up)])[:len(u) * up]
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete(signal.tf2ss(num, den), dt / up, method="zoh")
    y_fine = signal.dlsim((Ad, Bd, Cd, Dd, dt / up), fine)[1].ravel()[::up]
    assert np.max(np.abs(y - y_fine)) <= 1e-9 * np.max(np.abs(y_fine))


def test_fast_voltage_filter_is_the_identity_not_a_delay():
    """Voltage-side filters hand on the interval mean: a roll-off far above the sample rate changes nothing."""
    u = np.random.default_rng(2).standard_normal(300)
    m = truth.tf_from_poly([2 * np.pi * 1e6], [1.0, 2 * np.pi * 1e6])
    v = truth.lti_siso(m, 1e-3, u, average=True)
    assert np.max(np.abs(v - u)) < 1e-3


def test_every_withheld_effect_changes_the_output():
    """Each template (quick records, first tuning seed) moves TEST well above the sensor noise; nulls do not."""
    for case in C.make_cases([S.TUNING_SEEDS[0]], quick=True):
        _, info = R.records(case)
        if case.expected == "none":
            assert info["effect_rms_um"] == 0.0, case.name
        else:
            assert info["effect_to_noise"] > 2.0, (case.name, info)


def test_seed_sets_are_disjoint_and_the_heldout_set_is_frozen():
    assert not set(S.TUNING_SEEDS) & set(S.HELDOUT_SEEDS)
    fresh = set(S.FRESH_HELDOUT_SEEDS)
    assert len(fresh) == 2 and not fresh & (set(S.TUNING_SEEDS) | set(S.HELDOUT_SEEDS))
    assert S.IN_FAMILY_SEED["fresh"] not in (S.IN_FAMILY_SEED["tuning"], S.IN_FAMILY_SEED["heldout"])
    assert "frozen 2026-11-23, never looked at while tuning" in (ROOT / "bench/diagnosis/seeds.py").read_text()
    names = {c.template for c in C.make_cases(S.HELDOUT_SEEDS, quick=True)}
    assert names == {t.name for t in C.TEMPLATES}


def test_quick_cases_end_to_end_through_the_cli(tmp_path):
    """Generate → ``python -m piezo_ff_ros diagnose`` → scored rows and a summary with the contract's figures."""
    out = tmp_path / "bench.json"
    rc = R.main(["--quick", "--family", "out", "--only", f"null/fast_white@{S.TUNING_SEEDS[0]},"
                 f"rolloff/first_order@{S.TUNING_SEEDS[0]}", "--json", str(out), "--timeout", "600"])
    assert rc == 0
    res = json.loads(out.read_text())
    rows = res["rows"]
    assert {r["template"] for r in rows} == {"null/fast_white", "rolloff/first_order"}
    for r in rows:
        assert "error" not in r, r.get("error")
        assert isinstance(r["verdict"], str) and r["verdict"]
        assert r["correct"] == (r["verdict"] == r["expected"])
        assert 0 <= r["after"] <= r["before"] + 1e-9
    eff = next(r for r in rows if r["expected"] != "none")
    assert eff["before"] > 3 * eff["noise"]            # the withheld effect is visible on the held-out run
    s = res["summaries"]["tuning/out"]
    assert s["effect_cases"] == 1 and s["null_cases"] == 1
    assert set(s["calibration"]) >= {"high", "medium", "low"}
