"""The bad-input catalogue of ``bench/bench_bad_inputs.py`` (179 hostile CLI inputs) stays all clear.

The benchmark prints the counts (tried / clear / tracebacks / silently wrong / unclear); this test fails on the
first case that is not answered with a clear one-line error (or, for usable-but-damaged input, a warning), so a
regression names the case.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_bad_inputs", ROOT / "bench" / "bench_bad_inputs.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_every_bad_input_gets_a_clear_answer(tmp_path):
    bench = _bench()
    cases = bench.catalogue(tmp_path)
    assert len(cases) >= 150
    assert {c.category for c in cases} == {"csv", "mat", "mcap", "output", "options", "config"}
    bad = []
    for c in cases:
        verdict, line = bench.judge(c, *bench._run_inprocess(c.argv))
        if verdict != "clear":
            bad.append(f"{c.category}/{c.name}: {verdict}: {line}")
    assert not bad, "\n".join(bad)


def test_the_judge_is_not_blind():
    """The classifier flags a traceback, a silent acceptance, a multi-line or vague refusal and a missing warning."""
    bench = _bench()
    refuse = bench.Case("x", "y", ["check"], words=("units.voltage",))
    warn = bench.Case("x", "y", ["analyze"], expect="warn", words=("corrupt",))
    assert bench.judge(refuse, 2, "", "piezo-ff check: error: units.voltage: 'kV'\n", None)[0] == "clear"
    assert bench.judge(refuse, -1, "", "", "Traceback (most recent call last):\nKeyError: 1")[0] == "traceback"
    assert bench.judge(refuse, 1, "", "piezo-ff check: internal error: KeyError: 1\n", None)[0] == "traceback"
    assert bench.judge(refuse, 0, "all fine\n", "", None)[0] == "silently wrong"
    assert bench.judge(refuse, 2, "", "piezo-ff check: error: something\n", None)[0] == "unclear"
    assert bench.judge(refuse, 2, "", "a: error: units.voltage\nb: error: again\n", None)[0] == "unclear"
    assert bench.judge(warn, 0, "3 corrupt chunk(s) skipped\n", "", None)[0] == "clear"
    assert bench.judge(warn, 0, "fine\n", "", None)[0] == "silently wrong"
