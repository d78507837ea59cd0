"""Sim-to-real gap diagnosis (issue 5): where the gap lies, which unmodelled effect causes it, how far it shrinks.

``diagnose(cfg, train, test)`` → JSON-ready dict; :mod:`.report` writes the Markdown/PNG report and the corrected
config (``--apply``).  The candidate effects are the stages of :mod:`piezo_ff_ros.core.models.effects`.
"""
from .engine import DiagnosisOptions, diagnose, json_ready
from .synthetic import excitation, truth_cases, make_runs

__all__ = ["DiagnosisOptions", "diagnose", "json_ready", "excitation", "truth_cases", "make_runs"]
