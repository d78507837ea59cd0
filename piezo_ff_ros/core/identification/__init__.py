"""Identification of each stage from data on the system the previous stages leave (paper Fig. 3).

``bouc_wen`` (S0, sines) → ``creep`` (S_H, long steps) → ``dynamics`` (S_L, steps/PRBS) → H∞; ``pipeline`` chains
them.  Every stage reports its fit (MATLAB ``compare``, :func:`metrics.fit_percent`) on data it was not fitted on.
"""
from .goodness_of_fit import fit_percent, rmse

__all__ = ["fit_percent", "rmse"]
