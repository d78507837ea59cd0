"""The Kelvin–Voigt creep regressors of a long record, computed in one compiled pass, are the same numbers as the
filter they replace (``scipy.signal.lfilter`` at full length, then every k-th row): the fit's figures do not move."""
import math

import numpy as np
import pytest

from piezo_ff_ros.core.diagnosis import fit_output as F
from piezo_ff_ros.core.models import effects as fx


@pytest.mark.parametrize("tau, dt, k", [(0.05, 5e-5, 7), (3.0, 1e-3, 1), (0.5, 5e-5, 3), (40.0, 1e-2, 11)])
def test_the_one_pass_bank_equals_the_full_length_filters_bit_for_bit(tau, dt, k):
    y = np.cumsum(np.random.default_rng(7).normal(size=(20_011, 2)), axis=0) * 1e-7
    taus = (tau, tau * math.exp(1e-3), tau * math.exp(-1e-3))
    bank = np.empty((3, 2, -(-len(y) // k), 2))
    F._kv_bank(y, np.array([math.exp(-dt / t) for t in taus]), fx.CREEP_YREF, k, bank)
    for m, t in enumerate(taus):
        for r, ref in enumerate(F._kv_regs(y, t, dt)):
            np.testing.assert_array_equal(bank[m, r], ref[::k])
