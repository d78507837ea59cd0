"""ParameterBook while the compensator node declares its parameters: a declared value that is the base's own builds
no configuration (the node declares ~70 stage parameters and each build validates the whole stage), while an
override is still checked on its own, naming its field, and the cross-field check of everything runs at the end."""
from __future__ import annotations

import pytest

from piezo_ff_ros.core import parameter_book
from piezo_ff_ros.core.parameter_book import ParameterBook
from piezo_ff_ros.core.param_map import config_to_params


def _declare_all(book, base, overrides=None):
    """Declare every stage parameter in the node's order, as its on-set callback sees them; the first refusal."""
    overrides = overrides or {}
    for name, default in config_to_params(base).items():
        value = overrides.get(name, default)
        verdict = book.propose([(name, value)])
        if not verdict.successful:
            return verdict
        book.values[name] = value
    return None


def _counting(monkeypatch):
    calls = []
    real = parameter_book.params_to_config

    def counted(values, base):
        calls.append(len(values))
        return real(values, base)

    monkeypatch.setattr(parameter_book, "params_to_config", counted)
    return calls


@pytest.fixture
def base(paper_config):
    return paper_config


def test_declaring_the_base_values_builds_no_configuration(base, monkeypatch):
    calls = _counting(monkeypatch)
    book = ParameterBook(base)
    assert _declare_all(book, base) is None
    assert calls == []
    cfg = book.end_declarations()   # the one build of the whole set
    assert len(calls) == 1 and cfg.axes == base.axes


def test_an_override_while_declaring_is_still_checked_and_named(base, monkeypatch):
    calls = _counting(monkeypatch)
    book = ParameterBook(base)
    refused = _declare_all(book, base, {"vibration.t_r": -1.0})
    assert refused is not None and refused.reason.startswith("vibration.t_r") and "\n" not in refused.reason
    assert len(calls) == 1   # the override, and only it, was built
