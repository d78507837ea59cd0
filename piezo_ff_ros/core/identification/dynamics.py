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
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import scipy.signal

from ..config import DynamicsConfig
from ..lti import FactoredTF, TFMatrix
from ..recording.run import RunData
from .creep import step_events
from .metrics import fit_percent, greedy_order_search
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
    noisy = any(float(np.std(np.diff(r.y[:max(8, step_events(_inp(r))[0] if step_events(_inp(r)) else 8)], axis=0)))
                > 1e-4 * float(np.max(np.abs(r.y))) for r in runs)
    h = _impulse_estimates(runs, n, L, smooth=15 if noisy else 0)
    excited = sorted({j for r in runs for j in range(n) if np.ptp(_inp(r)[:, j]) > 0})

    def recs(rs: Sequence[RunData], scored: bool) -> list[dict[str, Any]]:
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
            out.append({"u": u, "y": y, "score": score, "moving": moving, "anchor": anchor})
        return out

    fit_recs = recs(runs, False)
    # slowest pole the records can determine: its response must settle (e^-3) within the shortest record
    pole_min = 3.0 / (min(len(r) for r in runs) * dt)
    val_recs = recs(validation, True) if validation else []

    def init(i: int, j: int, o: int) -> tuple[np.ndarray, Structure]:
        hij = h[i][j]
        if hij is None or o == 0:
            return np.zeros(0), Structure(0, 0)
        p = era_poles(hij, o, dt)
        th, st = poles_to_theta(p)
        return th, st

    separable = all(len(r["moving"]) == 1 for r in fit_recs)
    cache: dict[tuple[int, int, int], EntryModel] = {}

    def fit_entry(i: int, j: int, o: int) -> EntryModel:
        """One entry from the records where only input j moves (one axis at a time: the row separates)."""
        if (i, j, o) not in cache:
            rs = [r for r in fit_recs if r["moving"] == (j,)]
            structs, th0 = [Structure(0, 0)] * n, [np.zeros(0)] * n
            th0[j], structs[j] = init(i, j, o)
            models, _ = fit_row([r["y"][:, i] for r in rs], [[r["u"][:, jj] for r in rs] for jj in range(n)],
                                structs, th0, dt, max_nfev=max_nfev, pole_min=pole_min)
            cache[(i, j, o)] = models[j]
        return cache[(i, j, o)]

    def fit_with(i: int, orders: Mapping[int, int]) -> list[EntryModel]:
        if separable:
            return [fit_entry(i, j, orders[j]) if orders.get(j, 0) else EntryModel(Structure(0, 0), np.zeros(0),
                                                                                     np.zeros(0))
                    for j in range(n)]
        structs: list[Structure] = []
        th0: list[np.ndarray] = []
        for j in range(n):
            th, st = init(i, j, orders.get(j, 0))
            structs.append(st)
            th0.append(th)
        models, _ = fit_row([r["y"][:, i] for r in fit_recs], [[r["u"][:, j] for r in fit_recs] for j in range(n)],
                            structs, th0, dt, max_nfev=max_nfev, pole_min=pole_min)
        return models

    def entry_fits(models_by_row: Mapping[int, Sequence[EntryModel]], rs: Sequence[Mapping[str, Any]]
                   ) -> dict[tuple[int, int | None], float]:
        acc: dict[tuple[int, int | None], tuple[list[np.ndarray], list[np.ndarray]]] = {}
        for i, models in models_by_row.items():
            for rec in rs:
                yhat = simulate_row(models, [rec["u"][:, j] for j in range(n)], dt)
                w = rec["score"]
                a = rec["anchor"]
                # level before the held-out step: mean of the last 20 samples (one noisy sample would bias it)
                y0, yh0 = ((rec["y"][max(0, a - 19):a + 1, i].mean(), yhat[max(0, a - 19):a + 1].mean())
                           if a is not None else (0.0, 0.0))
                key: tuple[int, int | None] = (i, rec["moving"][0]) if len(rec["moving"]) == 1 else (i, None)
                acc.setdefault(key, ([], []))
                acc[key][0].append(rec["y"][w, i] - y0)
                acc[key][1].append(yhat[w] - yh0)
        return {k: float(fit_percent(np.concatenate(a), np.concatenate(b))[0]) for k, (a, b) in acc.items()}

    rows: list[list[EntryModel]] = []
    orders_out: dict[str, int] = {}
    for i in range(n):
        if order == "auto":
            scoring = val_recs or fit_recs

            def score(m: list[EntryModel], i: int = i) -> dict[int, float]:
                return {j: v for (ii, j), v in entry_fits({i: m}, scoring).items() if j is not None}

            orders, models = greedy_order_search(
                excited, {j: 2 for j in excited}, max_order, lambda o: o + 2, lambda o: fit_with(i, o), score, tol,
                lambda j, o: f"dynamics: G_L{axes[i]}{axes[j]} order {o}", say)
        else:
            if isinstance(order, dict):
                orders = {j: int(order.get(f"{axes[i]}{axes[j]}", order.get("default", 8))) for j in excited}
            else:
                orders = {j: int(order) for j in excited}
            models = fit_with(i, orders)
        rows.append(models)
        for j in range(n):
            orders_out[f"{axes[i]}{axes[j]}"] = int(models[j].structure.order)
    entries = [[rows[i][j].to_factored() if rows[i][j].structure.order else FactoredTF(0.0) for j in range(n)]
               for i in range(n)]
    cfg = DynamicsConfig(TFMatrix.from_nested(entries)).validate(axes)

    def named(d: Mapping[tuple[int, int | None], float]) -> dict[str, float]:
        return {(f"{axes[i]}{axes[j]}" if j is not None else axes[i]): v for (i, j), v in d.items()}

    fit_tr = named(entry_fits({i: rows[i] for i in range(n)}, fit_recs))
    fit_val = named(entry_fits({i: rows[i] for i in range(n)}, val_recs)) if val_recs else {}
    say(f"dynamics: orders {orders_out}; held-out fit {({k: round(v, 2) for k, v in fit_val.items()})} %")
    return DynamicsFit(config=cfg, orders=orders_out, fit_train=fit_tr, fit_validation=fit_val,
                       info={"method": "modal output error (variable projection), ERA init"})
