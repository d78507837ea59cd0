"""Import recorded runs from the formats a dSPACE/Simulink lab exports: CSV and MATLAB ``.mat``.

Both give a :class:`~piezo_ff_ros.core.recording.run.RunData` in SI units (s, V, m).  Anything that would make an
identification silently wrong is refused with a ``ValueError`` that names the file, the column/variable and the row:
missing columns, non-numeric cells, NaN/Inf, non-uniform or non-increasing time, and values whose order of
magnitude says the unit is not the one the format promises (displacements in µm or mm instead of m, voltages in mV
or kV-scale numbers instead of V).

``.npy``: the layout of the nonlinear-benchmark periodic records (the CubeSpec fine steering mirror set): a pair of
files ``u_<tag>.npy`` (V) and ``y_<tag>.npy`` (m) side by side, each ``[samples, channels, realizations, periods]``
(or ``[samples, channels]``), with the sample rate given by the caller (the layout holds none):
:func:`load_npy_realizations` gives one run per realization, its periods end to end.

CSV: a header ``t,u_x,u_y,x,y`` (any number of axes: every ``u_<axis>`` needs a matching ``<axis>`` column; an
optional ``r_<axis>`` column is read as the reference).  ``.mat``: variables ``t`` [N], ``u`` [N×axes], ``y``
[N×axes] (optionally ``r`` [N×axes] and ``axes``, a cell/char array of axis names).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, NoReturn, Sequence

import numpy as np

from .run import AXIS_ORDER, RunData, canonical_axes

__all__ = ["load_csv", "load_mat", "load_npy_realizations", "check_run_arrays", "MAX_DISPLACEMENT", "MAX_VOLTAGE",
           "MIN_DRIVE_VOLTAGE", "MIN_SAMPLE_RATE", "MAX_SAMPLE_RATE", "UNIFORM_TOL"]

#: largest plausible |displacement| of a piezo positioner [m]; above it the column is almost surely µm or mm
MAX_DISPLACEMENT = 5e-3
#: largest plausible |drive voltage| [V]; piezo drives stay well under 1.5 kV, larger numbers are mV or counts
MAX_VOLTAGE = 2000.0
#: a driven run whose largest |u| (all axes) lies between MAX_DISPLACEMENT and this [V] moves a piezo by nanometres:
#: the numbers are almost surely kV (5 V … 1 kV); smaller inputs are lengths in m (stage inputs Y_H, Y_L of the
#: creep and dynamics characterisations), an axis not driven at all (0 V) is fine
MIN_DRIVE_VOLTAGE = 1.0
#: plausible sample rates of a piezo record [Hz]: outside, the time column is almost surely in ms/µs (or ns)
MIN_SAMPLE_RATE = 100.0
MAX_SAMPLE_RATE = 10.0e6
#: relative tolerance on the sample period (recorders write t with ~6–9 significant digits)
UNIFORM_TOL = 1e-3


def _fail(path: Any, msg: str) -> NoReturn:
    raise ValueError(f"{path}: {msg}")


def _time_unit_hint(dt: float) -> str:
    for unit, scale in (("ms", 1e-3), ("µs", 1e-6), ("ns", 1e-9), ("minutes", 60.0)):
        if MIN_SAMPLE_RATE <= 1.0 / (dt * scale) <= MAX_SAMPLE_RATE:
            return f"the column looks like {unit} — convert to s"
    return "check its unit (s expected)"


def check_run_arrays(path: Any, t: np.ndarray, u: np.ndarray, y: np.ndarray, u_names: Sequence[str],
                     y_names: Sequence[str],
                     row_offset: int = 0, ref: np.ndarray | None = None,
                     min_drive_voltage: float = MIN_DRIVE_VOLTAGE) -> None:
    """Validate arrays of a run; raise ``ValueError`` saying what is wrong and where.

    ``row_offset`` maps array index 0 to the row number printed in messages (2 for a CSV with one header line,
    1 for MATLAB's 1-based indexing).  ``min_drive_voltage``: below it a driven run's voltages are taken for kV
    (0 for a layout whose unit is known to be V, e.g. an amplifier's input of a few hundred mV).
    """
    n = len(t)
    if n < 2:
        _fail(path, f"only {n} sample(s); need at least 2")
    for name, arr in [("t", t)] + [(nm, u[:, i]) for i, nm in enumerate(u_names)] + \
            [(nm, y[:, i]) for i, nm in enumerate(y_names)]:
        # a finite sum has no NaN/Inf to find (one pass over the column view, no copy and no mask of a long record);
        # an infinite one may be an overflow only
        with np.errstate(over="ignore", invalid="ignore"):
            if math.isfinite(float(np.sum(arr))):
                continue
        bad = ~np.isfinite(arr)
        if bad.any():
            k = int(np.argmax(bad))
            _fail(path, f"column {name!r}: {'NaN' if np.isnan(arr[k]) else 'Inf'} at row {k + row_offset} "
                        f"({int(bad.sum())} non-finite value(s) in total)")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        _fail(path, f"column 't': time does not increase at row {k + 1 + row_offset} "
                    f"(t={t[k + 1]:.9g} after t={t[k]:.9g})")
    dt0 = float(np.median(dt))
    if not MIN_SAMPLE_RATE <= 1.0 / dt0 <= MAX_SAMPLE_RATE:
        _fail(path, f"column 't': sample step {dt0:.6g} s ({1.0 / dt0:.6g} Hz) is not plausible in seconds for a "
                    f"piezo record ({MIN_SAMPLE_RATE:g} Hz … {MAX_SAMPLE_RATE:g} Hz expected); "
                    + _time_unit_hint(dt0))
    dev = np.abs(dt - dt0) > UNIFORM_TOL * dt0
    if dev.any():
        k = int(np.argmax(dev))
        _fail(path, f"column 't': non-uniform sampling at row {k + 1 + row_offset} (step {dt[k]:.9g} s, "
                    f"median step {dt0:.9g} s; {int(dev.sum())} irregular step(s)); resample before importing")
    for i, nm in enumerate(y_names):
        m = float(np.max(np.abs(y[:, i])))
        if m > MAX_DISPLACEMENT:
            k = int(np.argmax(np.abs(y[:, i])))
            unit = "µm" if m > 1.0 else "mm"
            _fail(path, f"column {nm!r}: displacement {y[k, i]:.6g} at row {k + row_offset} is not plausible in "
                        f"metres (|y| ≤ {MAX_DISPLACEMENT:g} m expected); the column looks like {unit} — "
                        f"convert to m")
    if ref is not None:
        m = float(np.max(np.abs(ref)))
        if not np.all(np.isfinite(ref)):
            k = int(np.argmax(~np.isfinite(ref).all(axis=1)))
            _fail(path, f"reference: non-finite value at row {k + row_offset}")
        if m > MAX_DISPLACEMENT:
            _fail(path, f"reference: |r| up to {m:.6g} is not plausible in metres; it looks like µm — convert to m")
    u_max = float(np.max(np.abs(u))) if u.size else 0.0
    # below MAX_DISPLACEMENT the input is a length (the creep/dynamics stages are characterised from Y_H, Y_L in m)
    if MAX_DISPLACEMENT < u_max < min_drive_voltage:
        i = int(np.argmax(np.max(np.abs(u), axis=0)))
        _fail(path, f"column {u_names[i]!r}: the largest drive voltage of the run is {u_max:.6g} — a piezo "
                    f"driven by < {MIN_DRIVE_VOLTAGE:g} V barely moves; the column looks like kV — convert to V")
    for i, nm in enumerate(u_names):
        m = float(np.max(np.abs(u[:, i])))
        if m > MAX_VOLTAGE:
            k = int(np.argmax(np.abs(u[:, i])))
            _fail(path, f"column {nm!r}: voltage {u[k, i]:.6g} at row {k + row_offset} is kV-scale (|u| ≤ "
                        f"{MAX_VOLTAGE:g} V expected); the column looks like mV or raw counts — convert to V")


def load_csv(path: str | Path, delimiter: str | None = None, axes: Sequence[str] | None = None) -> RunData:
    """Load a run from CSV with header ``t,u_<axis>…,<axis>…`` (s, V, m), uniformly sampled.

    Parameters
    ----------
    path : str or Path
        The file.
    delimiter : str, optional
        Field separator; sniffed from the header (``,``, ``;``, tab) when not given.
    axes : sequence of str, optional
        Axes wanted, in this order (each needs its ``u_<axis>`` and ``<axis>`` columns).  Default: every axis of
        the file in the order x, y, z, then the others — columns are read by name, never by position.

    Returns
    -------
    RunData

    Raises
    ------
    ValueError
        Missing/duplicate/unknown columns, non-numeric cells, NaN, non-uniform time, implausible units (kV, ms,
        µm …), each naming the file, the column and the row.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    text = p.read_text(errors="replace")
    lines = text.splitlines()
    # skip leading comment lines (# …) that some exporters write
    skip = 0
    while skip < len(lines) and (not lines[skip].strip() or lines[skip].lstrip().startswith("#")):
        skip += 1
    if skip >= len(lines):
        _fail(p, "empty file (no header line)")
    header_line = lines[skip]
    if delimiter is None:
        delimiter = max([",", ";", "\t"], key=header_line.count)
        if header_line.count(delimiter) == 0:
            delimiter = ","
    header = [h.strip().strip('"').strip() for h in next(csv.reader([header_line], delimiter=delimiter))]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        _fail(p, f"header line {skip + 1}: duplicate column(s) {dup}")
    if "t" not in header:
        _fail(p, f"header line {skip + 1}: missing column 't' (time in s); found {header}")
    file_axes = [h[2:] for h in header if h.startswith("u_") and len(h) > 2]
    if not file_axes:
        _fail(p, f"header line {skip + 1}: no input column 'u_<axis>' (voltage in V); found {header}")
    missing = [a for a in file_axes if a not in header]
    if missing:
        _fail(p, f"header line {skip + 1}: missing displacement column(s) {missing} for input(s) "
                 f"{['u_' + a for a in missing]}; found {header}")
    known = {"t"} | {f"u_{a}" for a in file_axes} | set(file_axes) | {f"r_{a}" for a in file_axes}
    unknown = [h for h in header if h not in known]
    if unknown:
        _fail(p, f"header line {skip + 1}: unknown column(s) {unknown}; expected t, u_<axis>, <axis> and optional "
                 f"r_<axis> for the axes {file_axes} (remove or rename the others)")
    refs = [a for a in file_axes if f"r_{a}" in header]
    if refs and len(refs) != len(file_axes):
        _fail(p, f"header line {skip + 1}: reference columns for {refs} only, missing "
                 f"{['r_' + a for a in file_axes if a not in refs]}")
    has_ref = bool(refs)
    if axes is None:
        axes = list(canonical_axes(file_axes))
    else:
        axes = [str(a) for a in axes]
        for a in axes:
            if a not in file_axes:
                _fail(p, f"axis {a!r}: no column 'u_{a}' (the file has axes {file_axes})")
    rows = []
    width = len(header)
    for lineno, line in enumerate(lines[skip + 1:], start=skip + 2):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = next(csv.reader([line], delimiter=delimiter))
        if len(cells) != width:
            _fail(p, f"row {lineno}: {len(cells)} field(s), header has {width}")
        vals = []
        for name, c in zip(header, cells):
            c = c.strip()
            try:
                vals.append(float(c))
            except ValueError:
                _fail(p, f"row {lineno}, column {name!r}: not a number ({c!r})")
        rows.append(vals)
    if not rows:
        _fail(p, "no data rows after the header")
    data = np.array(rows, float)
    col = {h: i for i, h in enumerate(header)}
    t = data[:, col["t"]]
    u = data[:, [col[f"u_{a}"] for a in axes]]
    y = data[:, [col[a] for a in axes]]
    ref = data[:, [col[f"r_{a}"] for a in axes]] if has_ref else None
    # row numbers in messages: the data row's line number in the file (blank/comment lines are rare; we map index
    # to line assuming none inside the data, which is what exporters write)
    check_run_arrays(p, t, u, y, [f"u_{a}" for a in axes], axes, row_offset=skip + 2, ref=ref)
    meta = {"source": str(p), "format": "csv", "columns": header}
    return RunData(t=t, u=u, y=y, axes=tuple(axes), reference=ref, meta=meta)


def load_mat(path: str | Path, axes: Sequence[str] | None = None) -> RunData:
    """Load a run from a MATLAB ``.mat`` file with variables ``t`` [N], ``u`` [N×axes], ``y`` [N×axes].

    Row/column vectors are accepted for one axis; ``u``/``y`` given as axes×N are transposed when unambiguous.
    MATLAB v7.3 (HDF5) files are refused with a message (save with ``-v7``).

    Raises
    ------
    ValueError
        Missing variables, shape mismatch, NaN, non-uniform time, implausible units (with the MATLAB row index).
    """
    import scipy.io

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    try:
        d = scipy.io.loadmat(str(p), squeeze_me=False)
    except NotImplementedError:
        _fail(p, "MATLAB v7.3 (HDF5) file; re-save with save(..., '-v7')")
    except Exception as exc:  # noqa: BLE001 - scipy raises several types for corrupt files
        _fail(p, f"not a readable MATLAB .mat file ({exc})")
    missing = [v for v in ("t", "u", "y") if v not in d]
    if missing:
        found = sorted(k for k in d if not k.startswith("__"))
        _fail(p, f"missing variable(s) {missing}; found {found} (expected t [N], u [N×axes], y [N×axes])")

    def num(name: str) -> np.ndarray:
        try:
            return np.asarray(d[name], float)
        except (TypeError, ValueError):
            _fail(p, f"variable {name!r} is not numeric")

    t = num("t").ravel()
    n = len(t)

    def as_matrix(name: str) -> np.ndarray:
        a = num(name)
        if a.ndim != 2:
            _fail(p, f"variable {name!r}: expected a matrix, got {a.ndim} dimension(s)")
        if a.shape[0] != n and a.shape[1] == n:
            a = a.T
        if a.shape[0] != n:
            _fail(p, f"variable {name!r}: shape {a.shape} does not match t with {n} samples")
        return a

    u, y = as_matrix("u"), as_matrix("y")
    if u.shape[1] != y.shape[1]:
        _fail(p, f"variables 'u' and 'y': {u.shape[1]} input(s) but {y.shape[1]} output(s)")
    k = u.shape[1]
    file_axes = ("x", "y", "z")[:k] if k <= 3 else tuple(f"a{i}" for i in range(k))
    if "axes" in d:
        try:
            names = [str(np.asarray(a).ravel()[0]) if np.asarray(a).size else "" for a in np.asarray(d["axes"]).ravel()]
            if len(names) == 1 and len(names[0]) == k:  # char array 'xy'
                names = list(names[0])
        except (TypeError, ValueError, IndexError):
            _fail(p, "variable 'axes': expected a cell or char array of axis names")
        if len(names) != k or not all(names) or len(set(names)) != k:
            _fail(p, f"variable 'axes': {names} does not give {k} distinct axis names (one per column of u)")
        file_axes = tuple(names)
    ref = as_matrix("r") if "r" in d else None
    if ref is not None and ref.shape[1] != k:
        _fail(p, f"variable 'r': {ref.shape[1]} column(s) for {k} axes")
    check_run_arrays(p, t, u, y, [f"u(:,{i + 1})" for i in range(k)], [f"y(:,{i + 1})" for i in range(k)],
                     row_offset=1, ref=ref)
    if axes is None:
        axes = canonical_axes(file_axes)
    for a in axes:
        if a not in file_axes:
            _fail(p, f"axis {a!r}: not in the file's axes {list(file_axes)}")
    cols = [file_axes.index(a) for a in axes]
    ref = None if ref is None else ref[:, cols]
    return RunData(t=t, u=u[:, cols], y=y[:, cols], axes=tuple(axes), reference=ref,
                   meta={"source": str(p), "format": "mat", "file_axes": list(file_axes)})


#: published test figures of the linear baseline (BLA, 28th-order state space trained at the same level) of the
#: CubeSpec fine steering mirror set, per record tag: RMSE [µm] and NRMSE [%] over the test realizations (Floren et
#: al., ISMA-USD 2024; upstream baseline_results/analyze_models.ipynb, as the set's SOURCE.md quotes them)
FSM_PUBLISHED_BLA = {"100mV_test": {"rmse_um": 0.114, "nrmse_percent": 8.38},
                     "200mV_test": {"rmse_um": 0.216, "nrmse_percent": 7.95},
                     "300mV_test": {"rmse_um": 0.228, "nrmse_percent": 5.63}}


def _published_bla(p: Path, tag: str) -> dict[str, Any] | None:
    """The published BLA figures of ``tag`` when ``p`` sits in the fine steering mirror set (by its folder name or
    its SOURCE.md), else None."""
    src = p.parent / "SOURCE.md"
    is_fsm = p.parent.name == "fsm_cubespec_piezo" or (src.is_file() and "fsm-benchmark-data" in src.read_text(
        errors="replace"))
    fig = FSM_PUBLISHED_BLA.get(tag) if is_fsm else None
    if fig is None:
        return None
    return {**fig, "model": "BLA (28th-order state space) trained at the same level",
            "dataset": "fsm_cubespec_piezo (Floren et al., ISMA-USD 2024, CC BY 4.0)"}


def load_npy_realizations(path: str | Path, sample_rate: float | None = None,
                          axes: Sequence[str] | None = None) -> list[RunData]:
    """Load the ``u_<tag>.npy`` / ``y_<tag>.npy`` pair of ``path`` (either file) as one run per realization.

    Parameters
    ----------
    path : str or Path
        ``u_<tag>.npy`` or ``y_<tag>.npy``; its partner must sit beside it.  Arrays ``[N, channels, R, P]``
        (N samples per period, R realizations, P periods: each run is the P periods end to end, so its first period
        holds the transient) or ``[N, channels]`` (one run); ``u`` in V, ``y`` in m.
    sample_rate : float
        [Hz]; required (the layout holds none; the fine steering mirror set: 6400 Hz).
    axes : sequence of str, optional
        Channel names (default x, y, z for up to three channels, else ``ch0``, ``ch1`` …).

    Returns
    -------
    list of RunData
        ``meta``: ``source``, ``experiment`` (``<tag>_r<realization>``), ``realization``, ``periods``,
        ``period_samples``; ``published_bla`` for a test record of the fine steering mirror set (its published
        BLA figures, :data:`FSM_PUBLISHED_BLA`).

    Raises
    ------
    ValueError
        No sample rate, no partner file, shapes that differ or are not of the layout, NaN/Inf, implausible units.
    """
    p = Path(path)
    m = p.name[:2].lower()
    if p.suffix.lower() != ".npy" or m not in ("u_", "y_"):
        _fail(p, "expected a u_<tag>.npy or y_<tag>.npy file of a u/y pair")
    if sample_rate is None or not (np.isfinite(sample_rate) and MIN_SAMPLE_RATE <= sample_rate <= MAX_SAMPLE_RATE):
        _fail(p, f"a .npy record carries no sample rate: give it (--sample-rate, {MIN_SAMPLE_RATE:g} … "
                 f"{MAX_SAMPLE_RATE:g} Hz), got {sample_rate!r}")
    tag = p.name[2:]
    files = {k: p.with_name(f"{k}_{tag}") for k in ("u", "y")}
    arrays = {}
    for k, f in files.items():
        if not f.exists():
            _fail(p, f"its partner {f.name} is not beside it")
        a = np.load(f, allow_pickle=False)
        if a.ndim == 2:
            a = a[:, :, None, None]
        if a.ndim != 4 or a.shape[0] < 2 or not np.issubdtype(a.dtype, np.number):
            _fail(f, f"shape {a.shape} is not [samples, channels, realizations, periods] (or [samples, channels])")
        arrays[k] = np.asarray(a, float)
    u, y = arrays["u"], arrays["y"]
    if u.shape != y.shape:
        _fail(p, f"u {u.shape} and y {y.shape} differ in shape (one output per input channel expected)")
    n, ch, n_real, n_per = u.shape
    names = tuple(axes) if axes is not None else (AXIS_ORDER[:ch] if ch <= len(AXIS_ORDER)
                                                  else tuple(f"ch{i}" for i in range(ch)))
    if len(names) != ch:
        _fail(p, f"{ch} channels but {len(names)} axis names {list(names)}")
    runs = []
    published = _published_bla(p, p.stem[2:])
    t = np.arange(n * n_per) / float(sample_rate)
    for r in range(n_real):
        ur = np.concatenate([u[:, :, r, k] for k in range(n_per)])
        yr = np.concatenate([y[:, :, r, k] for k in range(n_per)])
        check_run_arrays(f"{p} (realization {r})", t, ur, yr, [f"u_{a}" for a in names], list(names),
                         min_drive_voltage=0.0)
        runs.append(RunData(t=t.copy(), u=ur, y=yr, axes=names,
                            meta={"source": str(p), "experiment": f"{p.stem[2:]}_r{r}", "realization": r,
                                  "periods": n_per, "period_samples": n,
                                  **({"published_bla": published} if published else {})}))
    return runs

