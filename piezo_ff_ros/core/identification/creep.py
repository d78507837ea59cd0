"""Multivariable creep identification (paper §V-B): ``Y = [K + Cr(s)]·Y_H`` from long steps on S_H.

1. ``K`` from the settled values after the fast transient: at every step of the input (``Y_H``), the output change
   between just before the step and ``t_transient`` after it (mean over a short window), regressed on the input
   change (``A_f^{ij} = k_ij·Y_H``, Eq. 10; least squares when several steps/inputs are available).
2. ``Cr(s)``: the drift ``d = Y − K·Y_H`` (the paper's "A_f → A_m" evolution, fast transients masked out) is
   fitted per output row by continuous-time output error on a modal parametrisation (:mod:`.modal`) on block-
   averaged data (default 5 Hz: creep is slow, the averaging removes sensor noise).  The paper used MATLAB's
   Box–Jenkins; output error is its noise-model-free special case, the one that matters for simulation.
3. Fits (MATLAB ``compare``) are those of the *creep evolution*: drift and model drift both taken relative to their
   value at the first scored block after the step's fast transient (the paper's ``A_f``).  Why: after a step the
   output also carries the static error the identified hysteresis compensator leaves at that level (a few tenths of
   a µm, comparable with the creep itself after a step down); it is not creep and no Cr(s) can predict it.
4. Order per entry: given, or chosen automatically — start at 1 and raise an entry's order while its held-out fit
   improves by more than ``tol`` percentage points (the paper stopped at orders 1–3, fit ≥ 92 %).

Input runs must carry the input of S_H in ``run.reference`` (the characterisation records it there); held-out
runs may set ``meta['score_start']`` (sample index) to score only their second part (e.g. the step back down,
simulated from the start of the record).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..config import CreepConfig
from ..lti import FactoredTF, TFMatrix
from ..recording.run import RunData
from .goodness_of_fit import fit_percent, greedy_order_search
from .modal import EntryModel, ModalFit, Structure, fit_row, simulate_row

__all__ = ["CreepFit", "identify_creep", "step_events"]


@dataclass(frozen=True)
class CreepFit(ModalFit):
    """An identified creep model (K, Cr): ``config`` (SI) plus the orders, fits and facts of
    :class:`~.modal.ModalFit`."""

    config: CreepConfig = field(kw_only=True, metadata={"json": False})


def step_events(u: np.ndarray, rel: float = 0.005, gap: int = 400) -> list[int]:
    """Sample indices where some input starts a step: a move by more than ``rel`` of its range in one sample.

    Moves less than ``gap`` samples after the previous one belong to the same step (a slew-limited, ramped edge).
    """
    du = np.abs(np.diff(u, axis=0))
    rng = np.max(np.abs(u), axis=0)
    rng[rng == 0] = np.inf
    hit = np.any(du > rel * rng, axis=1)
    idx = np.nonzero(hit)[0] + 1
    out, last = [], None
    for i in idx:
        if last is None or i - last > gap:
            out.append(int(i))
        last = int(i)
    return out


def _input_of(run: RunData) -> np.ndarray:
    if run.reference is None:
        raise ValueError("creep identification: the run has no input record (reference = Y_H, the input of S_H)")
    return np.asarray(run.reference, float)


def _block(a: np.ndarray, m: int) -> np.ndarray:
    n = (len(a) // m) * m
    out: np.ndarray = a[:n].reshape(-1, m, a.shape[1]).mean(axis=1)
    return out


def _estimate_K(runs: Sequence[RunData], t_transient: float, window: float) -> np.ndarray:
    rows_du: list[np.ndarray] = []
    rows_dy: list[np.ndarray] = []
    for r in runs:
        u = _input_of(r)
        n_tr = int(round(t_transient / r.dt))
        n_w = max(1, int(round(window / r.dt)))
        for e in step_events(u):
            if e - n_w < 0 or e + n_tr + n_w > len(r):
                continue
            rows_du.append(u[e + n_tr] - u[e - 1])
            rows_dy.append(r.y[e + n_tr:e + n_tr + n_w].mean(axis=0) - r.y[e - n_w:e].mean(axis=0))
    if not rows_du:
        raise ValueError("creep identification: no usable step found in the input (need a step held ≥ "
                         f"{t_transient + window:.3g} s after it)")
    dU = np.array(rows_du)
    dY = np.array(rows_dy)
    if np.linalg.matrix_rank(dU) < dU.shape[1]:
        raise ValueError("creep identification: the steps do not excite every input (need a step on each axis)")
    Kt, *_ = np.linalg.lstsq(dU, dY, rcond=None)
    K: np.ndarray = Kt.T
    return K


def _prepare(runs: Sequence[RunData], K: np.ndarray, t_transient: float, fs_fit: float,
             validation: bool = False) -> list[dict[str, Any]]:
    """Block-averaged input/drift per run, plus cost masks and scoring masks."""
    recs = []
    for r in runs:
        u = _input_of(r)
        m = max(1, int(round(1.0 / (fs_fit * r.dt))))
        ub = _block(u, m)
        d = _block(r.y - u @ K.T, m)
        n = len(ub)
        mask = np.ones(n, bool)
        n_tr = int(np.ceil(t_transient / (m * r.dt))) + 1
        for e in step_events(u):
            b = e // m
            mask[b:b + n_tr + 1] = False
        score = mask.copy()
        if validation:
            s0 = int(r.meta.get("score_start", 0)) // m
            score[:s0] = False
        # the creep is the evolution after the fast part (A_f → A_m): scores are anchored at the first scored
        # block, so the static error the hysteresis compensator leaves at each level (not creep) is not counted
        idx = np.nonzero(score)[0]
        anchor = int(idx[0]) if len(idx) else 0
        moving = tuple(j for j in range(u.shape[1]) if np.ptp(u[:, j]) > 0)
        recs.append({"u": ub, "d": d, "mask": mask, "score": score, "dt": m * r.dt, "moving": moving,
                     "anchor": anchor})
    return recs


def _entry_fits(models_by_row: Mapping[int, Sequence[EntryModel]], recs: Sequence[Mapping[str, Any]],
                n: int) -> dict[tuple[int, int | None], float]:
    """Fit per entry 'ij' on records where only input j moves; per output 'i*' on the others."""
    out: dict[tuple[int, int | None], tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for i in models_by_row:
        for rec in recs:
            yhat = simulate_row(models_by_row[i], [rec["u"][:, j] for j in range(n)], rec["dt"])
            w = rec["score"]
            if w.sum() < 3:
                continue
            a = rec["anchor"]
            key: tuple[int, int | None] = (i, rec["moving"][0]) if len(rec["moving"]) == 1 else (i, None)
            out.setdefault(key, ([], []))
            out[key][0].append(rec["d"][w, i] - rec["d"][a, i])
            out[key][1].append(yhat[w] - yhat[a])
    return {k: float(fit_percent(np.concatenate(a), np.concatenate(b))[0]) for k, (a, b) in out.items()}


def _starts(order: int, T: float, t_min: float) -> list[tuple[np.ndarray, Structure]]:
    """Initial pole sets: real poles spread over [1/T, 1/t_min], and (order ≥ 2) one slow lightly damped pair."""
    lo, hi = 2.0 / T, 1.0 / max(t_min, 1e-6)
    starts: list[tuple[np.ndarray, Structure]] = []
    for span in ((lo, hi), (lo, np.sqrt(lo * hi))):
        starts.append((np.log(np.geomspace(span[0], span[1], order)), Structure(order, 0)))
    if order >= 2:
        real = np.log(np.geomspace(lo * 3, hi, order - 2)) if order > 2 else np.zeros(0)
        w = np.pi / T
        starts.append((np.concatenate([real, [np.log(0.05 * w), np.log(w)]]), Structure(order - 2, 1)))
    return starts


def identify_creep(runs: Sequence[RunData], validation: Sequence[RunData] = (),
                   order: str | int | dict[str, int] = "auto", max_order: int = 3,
                   t_transient: float = 0.2, window: float = 0.1, fs_fit: float = 5.0, tol: float = 0.5,
                   axes: Sequence[str] | None = None,
                   progress: Callable[[str], None] | None = None) -> CreepFit:
    """Identify ``K`` and ``Cr(s)`` from step records of S_H.

    Parameters
    ----------
    runs : sequence of RunData
        Fitting records; ``reference`` = the input Y_H [m], ``y`` = displacement [m].  Paper: a 20 µm step on one
        axis at a time, 600 s each.
    validation : sequence of RunData
        Held-out records (e.g. the steps back down), scored from ``meta['score_start']``.
    order : 'auto', int, or dict {'xy': int, …}
        Order of every Cr entry, or automatic choice (see module doc).
    max_order : int
        Upper bound of the automatic choice.
    t_transient : float
        Duration of the fast (vibration) transient after a step, excluded from the creep fit [s].
    window : float
        Averaging window for the settled values [s].
    fs_fit : float
        Rate of the block-averaged data the drift is fitted on [Hz].
    tol : float
        Minimum held-out fit gain (percentage points) for the automatic order to go up.
    axes : sequence of str, optional
        Axis names (default: the runs').
    """
    say = progress or (lambda s: None)
    if not runs:
        raise ValueError("creep identification: no fitting runs")
    axes = tuple(axes or runs[0].axes)
    n = len(axes)
    K = _estimate_K(runs, t_transient, window)
    say(f"creep: K = {np.array2string(K, precision=4)} from {sum(len(step_events(_input_of(r))) for r in runs)} "
        "step(s)")
    fit_recs = _prepare(runs, K, t_transient, fs_fit)
    val_recs = _prepare(validation, K, t_transient, fs_fit, validation=True) if validation else []
    T = max(len(r["u"]) * r["dt"] for r in fit_recs)
    dtf = fit_recs[0]["dt"]
    excited = sorted({j for r in fit_recs for j in r["moving"]})

    def fixed_order(i: int, j: int) -> int:
        if isinstance(order, dict):
            return int(order.get(f"{axes[i]}{axes[j]}", order.get("default", 2)))
        return int(order)

    def fit_with(i: int, orders: Mapping[int, int]) -> list[EntryModel]:
        """Best of several starts (by fitting cost) for row i with given per-input orders."""
        best: tuple[list[EntryModel], float] | None = None
        per_input = []
        for j in range(n):
            o = orders.get(j, 0)
            per_input.append(_starts(o, T, t_transient) if o else [(np.zeros(0), Structure(0, 0))])
        n_starts = max(len(s) for s in per_input)
        for s in range(n_starts):
            structs = [pi[min(s, len(pi) - 1)][1] for pi in per_input]
            th0 = [pi[min(s, len(pi) - 1)][0] for pi in per_input]
            models, cost = fit_row([r["d"][:, i] for r in fit_recs],
                                   [[r["u"][:, j] for r in fit_recs] for j in range(n)], structs, th0, dtf,
                                   [r["mask"] for r in fit_recs], max_nfev=60)
            if best is None or cost < best[1]:
                best = (models, cost)
        assert best is not None   # at least one start per row
        return best[0]

    rows: list[list[EntryModel]] = []
    orders_out: dict[str, int] = {}
    for i in range(n):
        if order == "auto":
            recs = val_recs or fit_recs
            orders, models = greedy_order_search(
                excited, {j: 1 for j in excited}, max_order, lambda o: o + 1, lambda o: fit_with(i, o),
                lambda m: _row_fits(m, recs, i, n), tol, lambda j, o: f"creep: Cr{axes[i]}{axes[j]} order {o}", say)
        else:
            orders = {j: fixed_order(i, j) for j in excited}
            models = fit_with(i, orders)
        rows.append(models)
        for j in range(n):
            orders_out[f"{axes[i]}{axes[j]}"] = orders.get(j, 0)
    entries = [[rows[i][j].to_factored() if rows[i][j].structure.order else FactoredTF(0.0) for j in range(n)]
               for i in range(n)]
    Kt = tuple(tuple(float(v) for v in row) for row in K)
    cfg = CreepConfig(K=Kt, Cr=TFMatrix.from_nested(entries)).validate(axes)

    def named(d: Mapping[tuple[int, int | None], float]) -> dict[str, float]:
        return {(f"{axes[i]}{axes[j]}" if j is not None else axes[i]): v for (i, j), v in d.items()}

    fit_tr = named(_entry_fits({i: rows[i] for i in range(n)}, fit_recs, n))
    fit_val = named(_entry_fits({i: rows[i] for i in range(n)}, val_recs, n)) if val_recs else {}
    say(f"creep: orders {orders_out}; held-out drift fit {({k: round(v, 2) for k, v in fit_val.items()})} %")
    return CreepFit(config=cfg, orders=orders_out, fit_train=fit_tr, fit_validation=fit_val,
                    info={"K_steps": True, "fs_fit": fs_fit})


def _row_fits(models: Sequence[EntryModel], recs: Sequence[Mapping[str, Any]], i: int, n: int) -> dict[int, float]:
    """{input j: fit of output i on records where only j moves}."""
    res = _entry_fits({i: models}, recs, n) if recs else {}
    return {j: v for (ii, j), v in res.items() if ii == i and j is not None}
