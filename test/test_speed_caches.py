"""The memories that save repeated work in a diagnosis give exactly the numbers of the work they save, and no caller
can change what a later caller gets."""
from __future__ import annotations

import numpy as np

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.lti import DiscreteModalSS, _ZOH_CACHE


def test_zoh_discretisation_is_remembered_as_independent_copies():
    """A second discretisation of the same transfer matrix gives the same arrays as a fresh one, in arrays of its
    own (writing into one result does not reach the next)."""
    cfg = load_config()
    _ZOH_CACHE.clear()
    fresh = DiscreteModalSS.zoh_from_tf_matrix(cfg.dynamics.G_L, cfg.dt)
    again = DiscreteModalSS.zoh_from_tf_matrix(cfg.dynamics.G_L, cfg.dt)
    for name in ("A", "B", "C", "D", "sizes"):
        assert np.array_equal(getattr(fresh, name), getattr(again, name))
        assert not np.shares_memory(getattr(fresh, name), getattr(again, name))
        assert getattr(again, name).flags.c_contiguous
    fresh.A[...] = 0.0
    third = DiscreteModalSS.zoh_from_tf_matrix(cfg.dynamics.G_L, cfg.dt)
    assert np.array_equal(third.A, again.A) and np.any(third.A)
    other_rate = DiscreteModalSS.zoh_from_tf_matrix(cfg.dynamics.G_L, cfg.dt / 2)
    assert not np.array_equal(other_rate.A, again.A)
