"""Sim-to-real gap diagnosis (issues 5, 8): where the gap lies, which unmodelled effect causes it (or that it is
reproducible but unnamed — ``unexplained`` — or not reproducible at all — ``none``), how far it shrinks, and which
experiment separates two explanations that fit equally well.

``diagnose(cfg, train, test)`` → :class:`~.results.DiagnosisResult` (a read-only mapping of its JSON report, the
arrays in ``.arrays``, ``to_json()``); :mod:`.stats` is the held-out test every verdict rests on,
:mod:`.flexible` the reference model behind the explainable share, :mod:`.discriminate` the experiment proposals,
:mod:`.report` the Markdown/PNG report and the corrected config (``--apply``).  The candidate effects are the stages
of :mod:`piezo_ff_ros.core.models.effects`.  Truth generators for benchmarks live under ``bench/``, not here.
"""
from .engine import DiagnosisArrays, DiagnosisOptions, DiagnosisResult, diagnose, json_ready

__all__ = ["DiagnosisOptions", "DiagnosisResult", "DiagnosisArrays", "diagnose", "json_ready"]
