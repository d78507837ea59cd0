"""MIMO dynamics identification (paper §VI-B): ``G_L(s)`` of S_L from step and/or PRBS records.

Method: per output row, every entry ``G_ij`` keeps its own poles (as the paper's per-entry Box–Jenkins fits), fitted
by **continuous-time output error on a modal parametrisation with variable projection** (:mod:`.modal`): poles are
the nonlinear unknowns (stable by construction), residues are solved by linear least squares, each mode's response
is the exact ZOH response to the recorded input (the discretisation the core simulates with).  Initial poles come
from **ERA (Ho–Kalman)** on each entry's impulse response (the derivative of a step response, or a least-squares
FIR estimate for PRBS/multisine records).  Why: output error is unbiased under white sensor noise (equation-error/ARX
is not), works for steps and PRBS alike, yields strictly proper, stable, per-entry factored transfer functions, and
needs only numpy/scipy — there is no maintained Python system-identification toolbox in this environment.

Order: given per entry, or chosen automatically — raise an entry's order by one pole pair (or one real pole) while
its held-out fit improves by more than ``tol`` percentage points.

Input runs carry the input of S_L (``Y_L``, m) in ``run.reference``; held-out runs may score only from
``meta['score_start']``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, NamedTuple, Sequence

import numpy as np
import scipy.signal

from ..config import DynamicsConfig
from ..lti import FactoredTF, TFMatrix
from ..recording.run import RunData
from .creep import step_events
from .goodness_of_fit import fit_percent, greedy_order_search
from .modal import EntryModel, ModalFit, Structure, era_poles, fit_row, poles_to_theta, simulate_row

__all__ = ["DynamicsFit", "identify_dynamics"]


@dataclass(frozen=True)
class DynamicsFit(ModalFit):
    """An identified G_L: ``config`` (SI) plus the orders, fits and facts of
    :class:`~.modal.ModalFit`."""

    config: DynamicsConfig = field(kw_only=True, metadata={"json": False})


def _inp(r: RunData) -> np.ndarray:
    if r.reference is None:
        raise ValueError("dynamics identification: the run has no input record (reference = Y_L, the input of S_L)")
    return np.asarray(r.reference, float)


def _baseline(r: RunData) -> np.ndarray:
    """Output offset: mean before the input first moves (records start at rest)."""
    u = _inp(r)
    mv = np.nonzero(np.any(np.abs(u - u[0]) > 0, axis=1))[0]
    k = int(mv[0]) if len(mv) else len(u)
    return r.y[:max(k, 1)].mean(axis=0) if np.allclose(u[0], 0) else np.zeros(r.y.shape[1])


def _impulse_estimates(runs: Sequence[RunData], n: int, L: int, smooth: int = 0) -> list[list[np.ndarray | None]]:
    """h[i][j]: impulse response estimates (length L+1) per entry."""
    h: list[list[np.ndarray | None]] = [[None] * n for _ in range(n)]
    for r in runs:
        u = _inp(r)
        y = r.y - _baseline(r)
        moving = [j for j in range(n) if np.ptp(u[:, j]) > 0]
        ev = step_events(u)
        if len(moving) == 1 and ev:
            j = moving[0]
            e = ev[0]
            amp = u[min(e + 400, len(u) - 1), j] - u[e - 1, j]   # the level reached after a ramped edge
            seg = y[e - 1:e + L] / amp          # y[e-1] = before the step; strictly proper: y[e] first to move
            for i in range(n):
                if h[i][j] is None:
                    # smoothed before differencing: sensor noise would otherwise dominate the impulse estimate
                    # (it only seeds ERA's poles; the output-error fit uses the raw data)
                    sm = scipy.signal.savgol_filter(seg[:, i] - seg[0, i], smooth, 3) if smooth else seg[:, i] - seg[0, i]
                    h[i][j] = np.diff(np.concatenate([[0.0], sm]))[:L + 1]
    for i in range(n):
        for j in range(n):
            if h[i][j] is None:  # FIR least squares over all records
                rows: list[np.ndarray] = []
                tgt: list[np.ndarray] = []
                for r in runs:
                    u = _inp(r)
                    y = r.y - _baseline(r)
                    N = len(u)
                    X = np.zeros((N, n * (L + 1)))
                    for jj in range(n):
                        for lag in range(1, L + 1):
                            X[lag:, jj * (L + 1) + lag] = u[:N - lag, jj]
                    rows.append(X)
                    tgt.append(y[:, i])
                X = np.vstack(rows)
                if np.linalg.norm(X[:, j * (L + 1):(j + 1) * (L + 1)]) == 0:
                    continue
                coef, *_ = np.linalg.lstsq(X, np.concatenate(tgt), rcond=None)
                h[i][j] = coef[j * (L + 1):(j + 1) * (L + 1)]
    return h


def _noisy(runs: Sequence[RunData]) -> bool:
    """Whether the sensor noise at rest (before the first step) is large enough to smooth the steps for ERA.

    Parameters
    ----------
    runs : sequence of RunData
        The fitting records.

    Returns
    -------
    bool
        True when any record's sample-to-sample spread over its rest exceeds 1e-4 of its largest output.
    """
    return any(float(np.std(np.diff(r.y[:max(8, step_events(_inp(r))[0] if step_events(_inp(r)) else 8)], axis=0)))
               > 1e-4 * float(np.max(np.abs(r.y))) for r in runs)


@dataclass(frozen=True)
class _Record:
    """One record as the fits and scores use it.

    Attributes
    ----------
    u, y : ndarray
        Input (Y_L) and output with its rest offset removed, ``[N, n]``.
    score : ndarray of bool
        Samples that count in the fit figure.
    moving : tuple of int
        The inputs that move in this record.
    anchor : int or None
        Held-out records scored from a held level: the last sample of that level (None: scored from zero).
    """

    u: np.ndarray
    y: np.ndarray
    score: np.ndarray
    moving: tuple[int, ...]
    anchor: int | None


def _records(rs: Sequence[RunData], n: int, scored: bool) -> list[_Record]:
    """The records of ``rs``; with ``scored``, held-out runs with ``meta['score_start']`` are scored from there.

    Parameters
    ----------
    rs : sequence of RunData
        Fitting or held-out runs.
    n : int
        Number of axes.
    scored : bool
        Honour ``score_start`` (held-out runs).

    Returns
    -------
    list of _Record
    """
    out = []
    for r in rs:
        u = _inp(r)
        y = r.y - _baseline(r)
        score = np.ones(len(r), bool)
        anchor: int | None = None
        if scored and int(r.meta.get("score_start", 0)) > 0:
            # a held-out step starting from a held level: scored as the change from that level (the static
            # error the hysteresis/creep compensators leave at a level is theirs, not G_L's)
            anchor = int(r.meta["score_start"]) - 1
            score[:anchor + 1] = False
        moving = tuple(j for j in range(n) if np.ptp(u[:, j]) > 0)
        out.append(_Record(u, y, score, moving, anchor))
    return out


_NO_ENTRY = Structure(0, 0)


@dataclass
class _RowFitter:
    """Output-error fits of the rows of G_L on the fitting records, entry by entry when the records allow it.

    Mutable: fitted entries are cached by ``(row, input, order)`` (the order search refits only the entry it
    changes).
    """

    h: list[list[np.ndarray | None]]      #: impulse response estimates (ERA's initial poles) per entry
    recs: list[_Record]                   #: the fitting records
    n: int
    dt: float
    max_nfev: int
    pole_min: float                       #: slowest pole the records can determine [1/s]
    cache: dict[tuple[int, int, int], EntryModel] = field(default_factory=dict)

    @property
    def separable(self) -> bool:
        """Every fitting record moves one input: each entry is fitted alone on its own records."""
        return all(len(r.moving) == 1 for r in self.recs)

    def init(self, i: int, j: int, o: int) -> tuple[np.ndarray, Structure]:
        """Initial parameters of entry ``(i, j)`` at order ``o``: ERA poles of its impulse estimate.

        Parameters
        ----------
        i, j : int
            Output row, input column.
        o : int
            Order (0: no entry).

        Returns
        -------
        theta : ndarray
        structure : Structure
        """
        hij = self.h[i][j]
        if hij is None or o == 0:
            return np.zeros(0), _NO_ENTRY
        p = era_poles(hij, o, self.dt)
        th, st = poles_to_theta(p)
        return th, st

    def fit_entry(self, i: int, j: int, o: int) -> EntryModel:
        """One entry from the records where only input j moves (one axis at a time: the row separates).

        Parameters
        ----------
        i, j : int
            Output row, input column.
        o : int
            Order.

        Returns
        -------
        EntryModel
        """
        if (i, j, o) not in self.cache:
            n = self.n
            rs = [r for r in self.recs if r.moving == (j,)]
            structs, th0 = [_NO_ENTRY] * n, [np.zeros(0)] * n
            th0[j], structs[j] = self.init(i, j, o)
            models, _ = fit_row([r.y[:, i] for r in rs], [[r.u[:, jj] for r in rs] for jj in range(n)],
                                structs, th0, self.dt, max_nfev=self.max_nfev, pole_min=self.pole_min)
            self.cache[(i, j, o)] = models[j]
        return self.cache[(i, j, o)]

    def fit_with(self, i: int, orders: Mapping[int, int]) -> list[EntryModel]:
        """Row ``i`` with the given order per input (absent or 0: no entry).

        Parameters
        ----------
        i : int
            Output row.
        orders : mapping
            Order per input column.

        Returns
        -------
        list of EntryModel
            One per input.
        """
        n = self.n
        if self.separable:
            return [self.fit_entry(i, j, orders[j]) if orders.get(j, 0) else EntryModel(_NO_ENTRY, np.zeros(0),
                                                                                          np.zeros(0))
                    for j in range(n)]
        structs: list[Structure] = []
        th0: list[np.ndarray] = []
        for j in range(n):
            th, st = self.init(i, j, orders.get(j, 0))
            structs.append(st)
            th0.append(th)
        models, _ = fit_row([r.y[:, i] for r in self.recs], [[r.u[:, j] for r in self.recs] for j in range(n)],
                            structs, th0, self.dt, max_nfev=self.max_nfev, pole_min=self.pole_min)
        return models


def _entry_fits(models_by_row: Mapping[int, Sequence[EntryModel]], rs: Sequence[_Record], n: int,
                dt: float) -> dict[tuple[int, int | None], float]:
    """Fit [%] per ``(row, input)`` over the records moving that one input (``(row, None)``: several inputs).

    Parameters
    ----------
    models_by_row : mapping
        The entries of each scored row.
    rs : sequence of _Record
        The records scored on.
    n : int
        Number of axes.
    dt : float
        Sample period [s].

    Returns
    -------
    dict
        ``{(i, j or None): fit %}``.
    """
    acc: dict[tuple[int, int | None], tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for i, models in models_by_row.items():
        for rec in rs:
            yhat = simulate_row(models, [rec.u[:, j] for j in range(n)], dt)
            w = rec.score
            a = rec.anchor
            # level before the held-out step: mean of the last 20 samples (one noisy sample would bias it)
            y0, yh0 = ((rec.y[max(0, a - 19):a + 1, i].mean(), yhat[max(0, a - 19):a + 1].mean())
                       if a is not None else (0.0, 0.0))
            key: tuple[int, int | None] = (i, rec.moving[0]) if len(rec.moving) == 1 else (i, None)
            acc.setdefault(key, ([], []))
            acc[key][0].append(rec.y[w, i] - y0)
            acc[key][1].append(yhat[w] - yh0)
    return {k: float(fit_percent(np.concatenate(a), np.concatenate(b))[0]) for k, (a, b) in acc.items()}


class _Rows(NamedTuple):
    """The fitted rows of G_L and the order of every entry."""

    models: list[list[EntryModel]]        #: ``models[i][j]``
    orders: dict[str, int]                #: ``{'xy': order, …}``


def _fit_rows(fitter: _RowFitter, order: str | int | dict[str, int], axes: tuple[str, ...], excited: list[int],
              max_order: int, tol: float, scoring: list[_Record], say: Callable[[str], None]) -> _Rows:
    """Every row of G_L, at the given orders or with the automatic order search.

    Parameters
    ----------
    fitter : _RowFitter
        Fits a row at given orders.
    order : 'auto', int or dict
        As :func:`identify_dynamics`.
    axes : tuple of str
        Axis names (entry ``ij`` is named ``axes[i] + axes[j]``).
    excited : list of int
        The inputs some fitting record moves (the others get no entry).
    max_order, tol : int, float
        Bounds of the automatic search.
    scoring : list of _Record
        The records the automatic search scores on.
    say : callable
        Progress messages.

    Returns
    -------
    _Rows
    """
    n = fitter.n
    rows: list[list[EntryModel]] = []
    orders_out: dict[str, int] = {}
    for i in range(n):
        if order == "auto":
            def score(m: list[EntryModel], i: int = i) -> dict[int, float]:
                return {j: v for (ii, j), v in _entry_fits({i: m}, scoring, n, fitter.dt).items() if j is not None}

            orders, models = greedy_order_search(
                excited, {j: 2 for j in excited}, max_order, lambda o: o + 2, lambda o: fitter.fit_with(i, o), score,
                tol, lambda j, o: f"dynamics: G_L{axes[i]}{axes[j]} order {o}", say)
        else:
            if isinstance(order, dict):
                orders = {j: int(order.get(f"{axes[i]}{axes[j]}", order.get("default", 8))) for j in excited}
            else:
                orders = {j: int(order) for j in excited}
            models = fitter.fit_with(i, orders)
        rows.append(models)
        for j in range(n):
            orders_out[f"{axes[i]}{axes[j]}"] = int(models[j].structure.order)
    return _Rows(rows, orders_out)


def _named(d: Mapping[tuple[int, int | None], float], axes: tuple[str, ...]) -> dict[str, float]:
    """Fit figures keyed by entry name (``'xy'``; a row's multi-input figure by the axis alone, ``'x'``).

    Parameters
    ----------
    d : mapping
        ``{(i, j or None): fit %}`` (:func:`_entry_fits`).
    axes : tuple of str
        Axis names.

    Returns
    -------
    dict
    """
    return {(f"{axes[i]}{axes[j]}" if j is not None else axes[i]): v for (i, j), v in d.items()}


def identify_dynamics(runs: Sequence[RunData], validation: Sequence[RunData] = (), order: str | int | dict[str, int] = "auto",
                      max_order: int = 8, tol: float = 0.25, era_length: float = 0.05, max_nfev: int = 40,
                      axes: Sequence[str] | None = None,
                      progress: Callable[[str], None] | None = None) -> DynamicsFit:
    """Identify ``G_L(s)`` (per-entry FactoredTF, strictly proper, stable) from records of S_L.

    Parameters
    ----------
    runs, validation : sequences of RunData
        Fitting / held-out records (``reference`` = Y_L [m], ``y`` [m]); paper: 20 µm steps on one axis at a time.
    order : 'auto', int or dict {'xy': int, …}
        Order of each entry.
    max_order : int
        Upper bound of the automatic order.
    tol : float
        Minimum held-out fit gain (percentage points) for the automatic order to go up.
    era_length : float
        Length of the impulse response used by ERA [s].
    max_nfev : int
        Budget of each output-error fit (function evaluations).  When every fitting record moves one input at a
        time (the paper's steps) each entry is fitted alone on its own records, and the order search refits only
        the entry it changes.
    """
    say = progress or (lambda s: None)
    if not runs:
        raise ValueError("dynamics identification: no fitting runs")
    axes = tuple(axes or runs[0].axes)
    n = len(axes)
    dt = runs[0].dt
    L = max(20, int(round(era_length / dt)))
    # noise level from the pre-step rest: decides whether the step responses are smoothed for ERA
    h = _impulse_estimates(runs, n, L, smooth=15 if _noisy(runs) else 0)
    excited = sorted({j for r in runs for j in range(n) if np.ptp(_inp(r)[:, j]) > 0})
    fit_recs = _records(runs, n, False)
    # slowest pole the records can determine: its response must settle (e^-3) within the shortest record
    pole_min = 3.0 / (min(len(r) for r in runs) * dt)
    val_recs = _records(validation, n, True) if validation else []
    fitter = _RowFitter(h, fit_recs, n, dt, max_nfev, pole_min)
    rows = _fit_rows(fitter, order, axes, excited, max_order, tol, val_recs or fit_recs, say)
    entries = [[m.to_factored() if m.structure.order else FactoredTF(0.0) for m in row] for row in rows.models]
    cfg = DynamicsConfig(TFMatrix.from_nested(entries)).validate(axes)
    by_row = dict(enumerate(rows.models))
    fit_tr = _named(_entry_fits(by_row, fit_recs, n, dt), axes)
    fit_val = _named(_entry_fits(by_row, val_recs, n, dt), axes) if val_recs else {}
    say(f"dynamics: orders {rows.orders}; held-out fit {({k: round(v, 2) for k, v in fit_val.items()})} %")
    return DynamicsFit(config=cfg, orders=rows.orders, fit_train=fit_tr, fit_validation=fit_val,
                       info={"method": "modal output error (variable projection), ERA init"})
