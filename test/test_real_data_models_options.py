"""The real-data bench's FSM options are checked before any data is read: an unknown channel structure or withheld
level is refused in one line with exit code 2 (bench/real_data_models.py)."""
import pytest

from bench import real_data_models as rdm


@pytest.mark.parametrize("option, value, named", [("--structures", "from_start,bogus", "bogus"),
                                                   ("--withheld", "100,250", "250")])
def test_an_unknown_structure_or_level_is_refused_in_one_line_before_any_fit(capsys, monkeypatch, option, value,
                                                                            named):
    def no_fit(*args, **kwargs):
        raise AssertionError("the FSM models were fitted despite the bad option")

    monkeypatch.setattr(rdm, "fsm", no_fit)
    assert rdm.main(["--only", "fsm", option, value]) == 2
    err = capsys.readouterr().err
    assert named in err and err.count("\n") == 1


def test_the_default_structures_are_known_ones():
    assert set(rdm.DEFAULT_STRUCTURES) <= set(rdm.STRUCTURES)
