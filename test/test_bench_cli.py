"""``piezo-ff bench`` runs end to end on a tiny budget, writes the JSON keys, and its baselines do the same maths.

Not a timed test: throughput figures are not asserted (the benchmark is a script; see BENCHMARKS.md).
"""
from __future__ import annotations

import json

import pytest

from piezo_ff_ros.cli import main


def test_bench_json_and_baselines_agree(tmp_path, capsys):
    out = tmp_path / "bench.json"
    rc = main(["bench", "--duration", "0.02", "--repeats", "1", "--baseline-duration", "0.01", "--block", "97",
               "--small-block", "0", "--no-hinf", "--json", str(out)])
    assert rc == 0
    res = json.loads(out.read_text())
    for key in ("full_chain_rt_factor", "baseline_rt_factor", "hinf_synthesis_s", "machine", "stages", "jit"):
        assert key in res
    assert res["full_chain_rt_factor"] > 0 and res["baseline_rt_factor"] > 0
    assert res["hinf_synthesis_s"] is None and "STAND-IN" in res["controller"]["controller"]
    assert set(res["stages"]) == {"bouc_wen", "hysteresis_comp", "creep_model", "creep_comp", "dynamics",
                                  "vibration_comp", "plant", "cascade", "full_chain"}
    for name, r in res["stages"].items():
        assert r["samples"] == 97 * 4  # 0.02 s at 20 kHz in blocks of 97 (rounded to whole blocks)
        for kind in ("naive", "forced_response"):
            if r[kind] is not None:
                assert r[kind]["max_rel_diff"] < 1e-9, (name, kind, r[kind]["max_rel_diff"])
    assert res["machine"]["cpu_count"] >= 1 and res["machine"]["numba"]
    assert "full chain" in capsys.readouterr().out


@pytest.mark.parametrize("argv,msg", [(["--duration", "0"], "--duration"), (["--repeats", "0"], "--repeats"),
                                      (["--baseline-duration", "nan"], "--baseline-duration")])
def test_bench_bad_options_are_clean_errors(argv, msg, capsys):
    assert main(["bench", *argv]) == 2
    assert msg in capsys.readouterr().err


def test_baselines_longer_than_the_signal_buffer_report_what_ran(tmp_path):
    """The baselines run on a slice of the 10 s signal buffer; asked for more, they ran on the whole buffer and the
    figures must say so (they claimed the asked duration, overstating samples and rate)."""
    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.bench.throughput import run_benchmark

    cfg_path = tmp_path / "slow.yaml"
    load_config().with_sample_rate(100.0).to_yaml(cfg_path)   # a 10 s buffer of 1000 samples
    res = run_benchmark(duration=0.5, repeats=1, small_block=0, baseline_duration=11.0, config=str(cfg_path),
                        hinf=False)
    assert res["baseline_duration_s"] == 10.0
    for st in res["stages"].values():
        for kind in ("naive", "forced_response"):
            if st[kind] is not None:
                assert st[kind]["samples"] == 1000 and st[kind]["extrapolated_from_s"] == 10.0
