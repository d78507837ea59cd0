"""A recording as the diagnosis takes it: the voltage the driver applied, and the gaps between experiments as segments.

The package's own recordings (``piezo-ff commission``, the recorder node) carry the commanded ``voltage`` and, from
the driver, ``voltage_applied``: every sample the device actually output (start ramps, slew limits, held blocks when a
block was dropped).  The plant saw the applied one, so the model replays that one where it was recorded.

Between experiments nothing is recorded: the run's rows there are NaN.  The diagnosis replays one continuous stretch
per part: :func:`split_record` cuts the record into its finite stretches, takes the training part from the stretches
before the split point and the held-out part from those after it (the longest of each), and hands the diagnosis the
record before the held-out stretch as its history (the voltage held across each gap, as a DAC holds its last
sample), so the held-out part starts from the state the record left, not from rest.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..recording.run import RunData

__all__ = ["APPLIED_TOPIC", "load_for_diagnosis", "split_record", "SplitRecord", "finite_stretches"]

#: the driver's topic of the voltage it applied (same block layout as ``voltage``)
APPLIED_TOPIC = "voltage_applied"
#: a stretch shorter than this is not used as a part (the diagnosis needs at least 200 samples)
MIN_STRETCH = 200


def load_for_diagnosis(path: str | Path, sample_rate: float | None = None, realization: int = 0) -> RunData:
    """Load a run; from an MCAP with a ``voltage_applied`` topic, ``u`` is the applied voltage (NaN where it was not
    recorded) and ``meta['voltage']`` says so (``'voltage'`` otherwise).

    Parameters
    ----------
    path : str or Path
        ``.mcap`` / rosbag2 directory, ``.csv``, ``.mat``, or one file of a ``u_<tag>.npy`` / ``y_<tag>.npy`` pair
        (the periodic-record layout of the fine steering mirror set: one run per realization).
    sample_rate : float, optional
        MCAP: the sample rate [Hz] to place the blocks at (when the file's metadata and stamps disagree); ``.npy``:
        the record's sample rate (required: the layout holds none).
    realization : int
        ``.npy`` only: which realization of the record is the run (0 by default).

    Returns
    -------
    RunData
    """
    from ..recording import load_run

    p = Path(path)
    if p.suffix.lower() == ".npy":
        from ..recording.importers import load_npy_realizations

        runs = load_npy_realizations(p, sample_rate=sample_rate)
        if not 0 <= int(realization) < len(runs):
            raise ValueError(f"{p.name}: realization {realization} asked, the record holds {len(runs)} (0 … "
                             f"{len(runs) - 1})")
        run = runs[int(realization)]
        run.meta["voltage"] = "voltage"
        return run
    is_mcap = p.suffix.lower() == ".mcap" or p.is_dir()
    if sample_rate is not None and not is_mcap:
        raise ValueError(f"--sample-rate applies to MCAP recordings only; {p.name} carries its own time column")
    run = load_run(p, sample_rate=sample_rate) if (is_mcap and sample_rate is not None) else load_run(p)
    run.meta["voltage"] = "voltage"
    if is_mcap and p.exists():
        applied = _applied_voltage(p, run)
        if applied is not None:
            run = RunData(run.t, applied, run.y, run.axes, run.reference, dict(run.meta))
            run.meta["voltage"] = APPLIED_TOPIC
    if sample_rate is not None:   # the rate was stated: the metadata's is not checked against the stamps again
        run.meta["metadata_sample_rate_overridden"] = run.meta.pop("metadata", None)
    return run


def _applied_voltage(path: Path, run: RunData) -> np.ndarray | None:
    """The ``voltage_applied`` blocks placed on ``run``'s sample grid (NaN where none), or None without that topic."""
    from ..recording.blocks import BLOCK_TYPE, deserialize_block
    from ..recording.mcap_scan import scan_mcap

    contents = scan_mcap(path)
    voltage_topic = (run.meta.get("blocks", {}).get("voltage") or {}).get("topic", "")
    prefix = voltage_topic.rsplit("/", 1)[0] if voltage_topic else None
    cands = [t for t, tn in contents.topics.items()
             if tn == BLOCK_TYPE and t.rstrip("/").split("/")[-1] == APPLIED_TOPIC]
    if prefix is not None and len(cands) > 1:
        cands = [t for t in cands if t.rsplit("/", 1)[0] == prefix]
    if len(cands) != 1:
        return None
    dt_ns, t0_ns, k_off = int(run.meta["dt_ns"]), int(run.meta["t0_ns"]), int(run.meta["k_offset"])
    n = len(run)
    out = np.full((n, len(run.axes)), np.nan)
    placed = 0
    for _, _, raw in contents.messages.get(cands[0], []):
        try:
            stamp, block, _ = deserialize_block(raw, run.axes)
        except ValueError:
            continue
        q, r = divmod(stamp - t0_ns, dt_ns)
        a = int(q + int(2 * r >= dt_ns)) - k_off
        lo, hi = max(a, 0), min(a + len(block), n)
        if hi > lo:
            out[lo:hi] = block[lo - a:hi - a]
            placed += hi - lo
    return out if placed else None


def finite_stretches(run: RunData) -> list[tuple[int, int]]:
    """``[start, stop)`` row ranges where the voltage and the displacement are finite on every axis."""
    ok = np.isfinite(run.u).all(axis=1) & np.isfinite(run.y).all(axis=1)
    d = np.diff(np.concatenate(([0], ok.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


@dataclass
class SplitRecord:
    """One record split for a diagnosis: the training part, the held-out part and the held-out part's history.

    Attributes
    ----------
    train, test : RunData
        Each one continuous finite stretch.
    history : RunData or None
        The record before ``test`` (voltage held across gaps), replayed before it, never scored.
    history_is_train : bool
        Whether ``history`` is ``train`` itself (one gap-free record split in two).
    notes : dict
        The report's ``input.segments``: the stretches, which ones were used, what was assumed.
    warnings : list of str
    """

    train: RunData
    test: RunData
    history: RunData | None
    history_is_train: bool
    notes: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _bridged(run: RunData, stop: int) -> RunData:
    """Rows ``0:stop`` made finite: the voltage held at its last finite value across each gap (first finite value
    before the first), the displacement interpolated (never scored: only a history's voltage drives the model)."""
    u = np.array(run.u[:stop], float)
    y = np.array(run.y[:stop], float)
    for arr in (u,):
        for j in range(arr.shape[1]):
            col = arr[:, j]
            ok = np.isfinite(col)
            if not ok.any():
                col[:] = 0.0
                continue
            idx = np.where(ok, np.arange(len(col)), 0)
            np.maximum.accumulate(idx, out=idx)
            first = int(np.flatnonzero(ok)[0])
            col[:] = col[idx]
            col[:first] = col[first]
    for j in range(y.shape[1]):
        col = y[:, j]
        ok = np.isfinite(col)
        col[:] = np.interp(np.arange(len(col)), np.flatnonzero(ok), col[ok]) if ok.any() else 0.0
    t = np.arange(stop) * run.dt
    return RunData(t, u, y, run.axes, None, dict(run.meta))


def split_record(run: RunData, fraction: float = 0.5) -> SplitRecord:
    """Split one record into a training and a held-out part, each a continuous finite stretch.

    A gap-free record: its first ``fraction`` and the rest (the training part is the held-out part's history).
    With gaps (NaN rows between experiments): the finite stretches are cut at the row where ``fraction`` of the finite
    samples lie before; the training part is the longest stretch before that row, the held-out part the longest after
    it, and the held-out part's history is the record before it with the voltage held across the gaps.

    Raises ``ValueError`` (one line) when either side has no stretch of at least :data:`MIN_STRETCH` samples.
    """
    stretches = finite_stretches(run)
    n = len(run)
    if stretches == [(0, n)] or not stretches:
        train, test = run.split(fraction)
        return SplitRecord(train, test, train, True)
    total = sum(b - a for a, b in stretches)
    want = fraction * total
    acc, cut = 0, stretches[-1][1]
    for a, b in stretches:
        if acc + (b - a) >= want:
            cut = a + int(round(want - acc))
            break
        acc += b - a
    before = [(a, min(b, cut)) for a, b in stretches if a < cut and min(b, cut) - a >= MIN_STRETCH]
    after = [(max(a, cut), b) for a, b in stretches if b > cut and b - max(a, cut) >= MIN_STRETCH]
    if not before or not after:
        raise ValueError(f"the record's finite stretches {stretches} (rows between them are gaps) leave no stretch "
                         f"of at least {MIN_STRETCH} samples on each side of the split at row {cut}; give --train "
                         "and --test, or another --split")
    tr = max(before, key=lambda s: s[1] - s[0])
    te = max(after, key=lambda s: s[1] - s[0])
    train, test = run.slice(*tr), run.slice(*te)
    history = _bridged(run, te[0]) if te[0] > 0 else None
    warnings = []
    if tr[0] > 0:
        warnings.append(f"train: the stretch used (rows {tr[0]}–{tr[1]}) starts {tr[0] * run.dt:.4g} s into the "
                        "record, not at rest: the model starts it from rest (slow states such as creep start off)")
    notes = {"stretches": [{"start": a, "stop": b} for a, b in stretches],
             "gaps": [{"start": b0, "stop": a1} for (_, b0), (a1, _) in zip(stretches, stretches[1:])],
             "split_row": int(cut), "train": {"start": tr[0], "stop": tr[1]}, "test": {"start": te[0], "stop": te[1]},
             "history": "the record before the held-out stretch, the voltage held across each gap (not scored)",
             "unused_samples": int(n - (tr[1] - tr[0]) - (te[1] - te[0]))}
    return SplitRecord(train, test, history, False, notes, warnings)
