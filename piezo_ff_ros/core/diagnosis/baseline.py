"""The first phases of a diagnosis: the runs and options checked, the nominal model's replay of them (residual, noise
floor, NRMSEs) and where the gap lies (localisation and effect signatures).

Each phase hands the next a frozen record: :class:`_Setup` (the checked inputs), :class:`_Replay` (the nominal
replay), :class:`_Localised`.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..config import PiezoConfig
from ..models.effects import EFFECTS, build_plant
from ..recording.run import RunData
from .candidates import CANDIDATES
from .replay import (Windows, check_run, check_scale, input_period, model_for_run, noise_floor, noise_floor_periodic, residual,
                     simulate)
from .residual_signatures import signatures
from .results import DiagnosisOptions
from .where import localise

__all__ = ["LOCALISE_SAMPLES", "LONG_NOISE_SAMPLES"]

#: above this many held-out samples, localisation and signatures use stretches of the run
LOCALISE_SAMPLES = 300_000
#: a long run's white-noise floor is measured on this many samples (8 stretches spread over the run)
LONG_NOISE_SAMPLES = 1_000_000

#: effects ``[(name, params)]`` added to the nominal model
_Effects = Sequence[tuple[str, Mapping[str, Any]]]


@dataclass(frozen=True)
class _Setup:
    """The checked inputs of one diagnosis.

    Attributes
    ----------
    cfg : PiezoConfig
        The nominal model at the runs' sample rate.
    train, test : RunData
        The training and the held-out run.
    test_ext : RunData
        ``test`` preceded by its history (``test`` itself without one).
    history : int
        How many samples of history precede ``test`` in ``test_ext``.
    history_is_train : bool
        Whether the history is the training run itself (its nominal replay is then a slice of ``test_ext``'s).
    opts : DiagnosisOptions
        The options, with the long-run budget applied.
    long_run : bool
        Whether a run is longer than ``opts.long_run_samples``.
    discriminate : RunData or None
        The run that decides between tied candidates.
    warnings : tuple of str
        What the diagnosis had to assume (a run that does not start at rest …): the report's ``warnings``.
    """

    cfg: PiezoConfig
    train: RunData
    test: RunData
    test_ext: RunData
    history: int
    history_is_train: bool
    opts: DiagnosisOptions
    long_run: bool
    discriminate: RunData | None
    warnings: tuple[str, ...] = ()


#: a run "starts at rest" when its first voltage is within this share of its largest voltage magnitude (of 0 V)
REST_SHARE = 0.02


def _not_at_rest(run: RunData, name: str) -> list[str]:
    """A warning when ``run`` starts away from 0 V: the model starts it from rest, the plant did not."""
    u0 = np.abs(run.u[0])
    scale = float(np.max(np.abs(run.u)))
    if scale > 0 and float(np.max(u0)) > REST_SHARE * scale:
        return [f"{name} starts at {np.round(run.u[0], 3).tolist()} V, not at rest: the model starts it from 0 V, "
                "so its first part holds a start-up transient (hysteresis, creep) the plant did not have; record "
                "from rest, or give the record that precedes it (diagnose --data splits one record and replays "
                "the training part first)"]
    return []


def _check(cfg: PiezoConfig, train: RunData, test: RunData, opts: DiagnosisOptions, test_history: RunData | None,
           discriminate: RunData | None) -> _Setup:
    """Check the runs and the options (``ValueError`` naming the problem), the model at the runs' rate, the long-run
    budget, the held-out run extended by its history."""
    check_run(train, "train")
    check_run(test, "test")
    cfg = model_for_run(cfg, train)
    if abs(test.sample_rate - cfg.sample_rate) > 1e-6 * cfg.sample_rate:
        raise ValueError(f"train is sampled at {cfg.sample_rate:g} Hz but test at {test.sample_rate:g} Hz")
    model_for_run(cfg, test)
    if discriminate is not None:
        check_run(discriminate, "discriminate")
        model_for_run(cfg, discriminate)
        if abs(discriminate.sample_rate - cfg.sample_rate) > 1e-6 * cfg.sample_rate:
            raise ValueError(f"discriminate: sampled at {discriminate.sample_rate:g} Hz, train at "
                             f"{cfg.sample_rate:g} Hz")
    unknown = [c for c in opts.candidates if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"unknown candidate effect(s) {unknown}; known: {list(CANDIDATES)}")
    long_run = max(len(train), len(test)) > opts.long_run_samples
    if long_run:
        opts = dataclasses.replace(opts, fit_samples=min(opts.fit_samples, opts.long_fit_samples),
                                   score_samples=min(opts.score_samples, opts.long_score_samples),
                                   warmup_s=min(opts.warmup_s, opts.long_warmup_s))
    # the held-out run, extended by its history when it was split from a longer record
    H = 0
    test_ext = test
    if test_history is not None:
        if test_history is not train:  # the training run (a --data split) is checked above
            check_run(test_history, "test history")
        H = len(test_history)
        test_ext = RunData(np.arange(H + len(test)) * cfg.dt, np.vstack([test_history.u, test.u]),
                           np.vstack([test_history.y, test.y]), test.axes)
    warnings = _not_at_rest(train, "train") + (_not_at_rest(test, "test") if test_history is None else [])
    return _Setup(cfg, train, test, test_ext, H, test_history is train, opts, long_run, discriminate,
                  tuple(warnings))


@dataclass(frozen=True)
class _Replay:
    """The nominal model's replay of the runs.

    Attributes
    ----------
    y_ext_nom, y_test_nom, y_train_nom : ndarray [N, axes]
        The nominal replay of the extended held-out run, of the held-out run, of the training run [m].
    sigma : ndarray [axes]
        The white-noise floor per axis [m]; ``sigma2`` its mean square.
    sigma2 : float
    noise_method : str
        How the floor was measured.
    train_nrmse, before_nrmse : float
        The nominal model's NRMSE on TRAIN and on TEST [%] (offsets removed).
    test_den : float
        ``‖y − ȳ‖`` of the held-out run (the NRMSE's denominator).
    """

    y_ext_nom: np.ndarray
    y_test_nom: np.ndarray
    y_train_nom: np.ndarray
    sigma: np.ndarray
    sigma2: float
    noise_method: str
    train_nrmse: float
    test_den: float
    before_nrmse: float


def _replay(s: _Setup, log: Callable[[str], None], t_start: float) -> _Replay:
    """The nominal replay of both runs, the held-out residual's noise floor and the NRMSEs before any correction."""
    cfg, train, test, H = s.cfg, s.train, s.test, s.history
    y_ext_nom = simulate(cfg, s.test_ext.u, [])
    y_test_nom = y_ext_nom[H:]
    y_train_nom = y_ext_nom[:H] if s.history_is_train else simulate(cfg, train.u, [])
    # a measured scale the model cannot have (µm stored as m) is refused before any fit tries to explain it
    check_scale(train, y_train_nom, "train")
    check_scale(test, y_test_nom, "test")
    r_test = residual(test.y, y_test_nom)
    period = input_period(test.u)
    # periodic excitation: the noise is what differs between periods; else the residual's second difference
    sigma = noise_floor_periodic(test.y, period) if period else \
        noise_floor(r_test, LONG_NOISE_SAMPLES if s.long_run else None)
    noise_method = f"period-to-period difference (period {period} samples)" if period else "second difference"
    sigma2 = float(np.mean(sigma ** 2))
    train_nrmse = _centered_nrmse(train.y, y_train_nom)
    test_den = _centered_norm(test.y)
    before_nrmse = _centered_nrmse(test.y, y_test_nom, test_den)
    log(f"replay: train {train_nrmse:.3f} %, "
        f"test {before_nrmse:.3f} % NRMSE; "
        f"white noise floor {np.round(sigma * 1e9, 1).tolist()} nm by {noise_method} "
        f"({time.perf_counter() - t_start:.1f} s)")
    return _Replay(y_ext_nom, y_test_nom, y_train_nom, sigma, sigma2, noise_method, train_nrmse, test_den,
                   before_nrmse)


def _sim_test(s: _Setup, rep: _Replay, effects: _Effects) -> np.ndarray:
    """The held-out run replayed by the nominal model plus ``effects`` (after its history)."""
    # displacement-side effects only: applied to the nominal output, no need to re-run the plant
    if all(EFFECTS[e].position == "post" for e, _ in effects):
        plant = build_plant(s.cfg, effects)
        y = rep.y_ext_nom
        for st in plant.post:
            st.reset()
            y = st.process(y)
        return y[s.history:]
    return simulate(s.cfg, s.test_ext.u, effects)[s.history:]


@dataclass(frozen=True)
class _Localised:
    """Where the held-out gap lies.

    Attributes
    ----------
    where : dict
        The report's ``where`` (:func:`~.where.localise`, plus the training NRMSE).
    sig : dict
        The residual's effect signatures (:func:`~.residual_signatures.signatures`).
    """

    where: dict[str, Any]
    sig: dict[str, float]


def _localise(s: _Setup, rep: _Replay, log: Callable[[str], None], t_start: float) -> _Localised:
    """Localisation and signatures of the held-out residual."""
    cfg, test, y_test_nom = s.cfg, s.test, rep.y_test_nom
    # a long run is localised on 8 contiguous stretches spread over it (LOCALISE_SAMPLES in all): descriptive
    # statistics do not need every sample, and the 10-minute run must stay fast
    lw = Windows.spread(len(test), LOCALISE_SAMPLES, 8)
    lt = (lambda x: x) if lw.is_whole else lw.take
    where = localise(lt(test.u), lt(test.y), lt(y_test_nom), cfg.dt, tuple(cfg.axes), rep.sigma)
    if not lw.is_whole:
        where["sampled_on"] = f"{lw.n} samples in {len(lw.spans)} stretches spread over the held-out run"
    where["train_nrmse_percent"] = rep.train_nrmse
    sig = signatures(lt(test.u), lt(y_test_nom), residual(lt(test.y), lt(y_test_nom)), cfg.dt, rep.sigma)
    log(f"localised ({time.perf_counter() - t_start:.1f} s)")
    return _Localised(where, sig)


def _centered_norm(x: np.ndarray) -> float:
    """``‖x − x̄‖`` (each column's mean removed), without the temporaries of the plain expression."""
    x = np.asarray(x, float)
    m = np.full(len(x), 1.0 / max(len(x), 1)) @ x
    c = x - m
    return float(math.sqrt(float(np.einsum("ij,ij->", c, c))))


def _centered_nrmse(y: np.ndarray, y_hat: np.ndarray, den: float | None = None) -> float:
    """``nrmse_percent(y − ȳ, ŷ − ŷ̄)`` (the NRMSE with each run's offset removed), in one pass per operand;
    ``den`` = :func:`_centered_norm` of ``y`` when already known."""
    den = _centered_norm(y) if den is None else den
    return float(100.0 * _centered_norm(np.asarray(y, float) - y_hat) / max(den, 1e-300))
