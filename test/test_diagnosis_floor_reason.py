"""A held-out gap at or below the white-noise floor: the reason does not print a share of a gap above the floor
(it read "removes 3e+289 %" on a null); above the floor it prints that share as before."""
from piezo_ff_ros.core.diagnosis.decision import Scored, _confidence
from piezo_ff_ros.core.diagnosis.fit_common import FitResult


def _scored(excess_shrink, above):
    fit = FitResult("input_delay", {}, {}, [], 1, float("nan"))
    return Scored(fit, 1.0, 0.5, 0.0, 1.0, 0.7, True, 0.0,
                  {"z": 40.0, "share": 1.0, "excess_shrink": excess_shrink, "gap_above_floor": above})


def test_no_gap_above_the_floor_prints_no_share_of_it():
    _, why = _confidence(_scored(3e287, False), None, None, 3.0)
    assert "e+2" not in why and "% of the gap above the white-noise floor" not in why
    assert "not above the white-noise floor" in why


def test_a_gap_above_the_floor_prints_its_share():
    _, why = _confidence(_scored(0.93, True), None, None, 3.0)
    assert "removes 93 % of the gap above the white-noise floor" in why
