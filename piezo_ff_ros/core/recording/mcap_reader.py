"""Run reassembly: the contract's block topics of a ROS 2 recording into sample-aligned arrays (:func:`read_run`).

The block topics (``reference``, ``voltage``, ``displacement``: ``sensor_msgs/msg/PointCloud2`` tables, see
:mod:`.blocks`) are placed by sample index, from our recordings or any other ROS 2 MCAP writer (``rosbags`` bare
``.mcap``, a rosbag2 directory with ``metadata.yaml``).
"""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, NamedTuple

import numpy as np

from .blocks import BLOCK_TYPE, deserialize_block, deserialize_message, sample_period_ns
from .mcap_scan import MAX_LISTED_RANGES, McapContents, scan_mcap
from .run import RunData, canonical_axes
from .schemas import BLOCK_ROLES, DIAGNOSTICS_TYPE, EXPERIMENT_TYPE

__all__ = ["read_run"]


def _pick_topic(contents: McapContents, role: str, type_name: str, namespace: str | None) -> str | None:
    cands = [t for t, tn in contents.topics.items() if tn == type_name and t.rstrip("/").split("/")[-1] == role]
    if namespace is not None:
        want = "/" + "/".join(x for x in (namespace.strip("/"), role) if x)
        cands = [t for t in cands if t == want or t.lstrip("/") == want.lstrip("/")]
    if len(cands) > 1:
        raise ValueError(f"several {role} topics {sorted(cands)}; choose one with namespace=")
    return cands[0] if cands else None


def _infer_dt_ns(stamp_lists: list[list[tuple[int, int]]]) -> int | None:
    """Most common (stamp difference / block width) over consecutive blocks of each topic."""
    votes: Counter[int] = Counter()
    for blocks in stamp_lists:
        srt = sorted(blocks)
        for (s0, n0), (s1, _) in zip(srt, srt[1:]):
            d = s1 - s0
            if n0 > 0 and d > 0 and d % n0 == 0:
                votes[d // n0] += 1
    return votes.most_common(1)[0][0] if votes else None


#: a gap between blocks is bridged (kept as NaN rows) up to this many samples, or the number of samples the
#: recording holds if larger; beyond that, the blocks on the smaller side are outliers (memory stays ≤ ~2× the data)
MIN_BRIDGED_GAP = 1_000_000


def _split_outliers(decoded: Blocks, dt_ns: int) -> tuple[Blocks, Blocks]:
    """Keep the blocks of the main time span; return ``(kept, outliers)`` per role.

    Blocks (all topics together) are grouped into clusters separated by gaps larger than
    ``max(MIN_BRIDGED_GAP, samples held)`` sample periods; the cluster holding the most samples is the recording,
    the others are outliers (never allocated).
    """
    items = sorted((s, s + len(b) * dt_ns, role, i) for role, blks in decoded.items() for i, (s, b) in enumerate(blks))
    if not items:
        return decoded, {}
    per_role: Counter[str] = Counter()
    for role, blks in decoded.items():
        per_role[role] = sum(len(b) for _, b in blks)
    max_gap_ns = max(MIN_BRIDGED_GAP, max(per_role.values())) * dt_ns
    clusters: list[tuple[int, list[tuple[str, int]]]] = []
    cur: list[tuple[str, int]] = []
    cur_end, cur_n = 0, 0
    for start, end, role, i in items:
        if cur and start - cur_end > max_gap_ns:
            clusters.append((cur_n, cur))
            cur, cur_n = [], 0
        cur.append((role, i))
        cur_n += (end - start) // dt_ns
        cur_end = end if len(cur) == 1 else max(cur_end, end)
    clusters.append((cur_n, cur))
    if len(clusters) == 1:
        return decoded, {r: [] for r in decoded}
    main = set(max(clusters, key=lambda c: c[0])[1])
    kept = {r: [blk for i, blk in enumerate(blks) if (r, i) in main] for r, blks in decoded.items()}
    outs = {r: [blk for i, blk in enumerate(blks) if (r, i) not in main] for r, blks in decoded.items()}
    return kept, outs


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) ranges where ``mask`` is True."""
    if not mask.any():
        return []
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _diagnostics_summary(raw_msgs: Iterable[tuple[int, int, bytes]]) -> dict[str, Any]:
    summary: dict[str, Any] = {"messages": 0, "malformed": 0, "status": {}}
    for _, _, raw in raw_msgs:
        try:
            msg = deserialize_message(raw, DIAGNOSTICS_TYPE)
        except ValueError:
            summary["malformed"] += 1
            continue
        summary["messages"] += 1
        for st in msg.status:
            level = int(st.level[0] if isinstance(st.level, (bytes, bytearray)) else st.level)
            entry = summary["status"].setdefault(st.name, {"count": 0, "max_level": 0, "errors": 0})
            entry["count"] += 1
            entry["max_level"] = max(entry["max_level"], level)
            entry["errors"] += int(level >= 2)
            entry.update(level=level, message=st.message, hardware_id=st.hardware_id,
                         values={kv.key: kv.value for kv in st.values})
    return summary


def _as_int(v: Any) -> int:
    """An integer from JSON (an integral float too); ``ValueError`` otherwise (bools, text, 1.5)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
        raise ValueError(f"not an integer: {v!r}")
    return int(v)


def _experiment_markers(raw_msgs: Iterable[tuple[int, int, bytes]], t0_ns: int, dt_ns: int,
                        warnings: list[str]) -> list[dict[str, Any]]:
    markers: list[dict[str, Any]] = []
    seen: set[tuple[str, int]] = set()
    for log_time, _, raw in raw_msgs:
        try:
            text = deserialize_message(raw, EXPERIMENT_TYPE).data
        except ValueError:
            warnings.append("experiment: undecodable message skipped")
            continue
        try:
            info = json.loads(text)
            if not isinstance(info, dict):
                raise TypeError
        except (TypeError, ValueError):
            warnings.append(f"experiment: marker {text[:60]!r} is not a JSON object; skipped")
            continue
        try:
            if "stamp_ns" in info:
                q, r = divmod(_as_int(info["stamp_ns"]) - t0_ns, dt_ns)
                k0 = q + (2 * r >= dt_ns)
            elif "k0" in info:
                k0 = _as_int(info["k0"])
            else:
                warnings.append(f"experiment: marker {info.get('name')!r} has neither k0 nor stamp_ns; skipped")
                continue
            for name in ("k1", "n"):
                if name in info:
                    info[name] = _as_int(info[name])
        except (TypeError, ValueError):
            warnings.append(f"experiment: marker {text[:60]!r}: k0/stamp_ns/k1/n not integers; skipped")
            continue
        key = (str(info.get("name", info.get("experiment", ""))), k0)  # Experiment.meta() says "experiment"
        if key in seen:  # transient-local redelivery or several publishers: one marker
            continue
        seen.add(key)
        markers.append({"name": key[0], "k0": int(k0), "stages": info.get("stages"), "info": info,
                        "log_time_ns": int(log_time)})
    markers.sort(key=lambda m: m["k0"])
    return markers


Blocks = dict[str, list[tuple[int, np.ndarray]]]


def _metadata_axes(md: dict[str, Any], warnings: list[str]) -> list[str] | None:
    """The axis names of the ``piezo_ff_ros`` metadata record in the fixed x, y, z order, or None (absent/invalid)."""
    if "axes" not in md:
        return None
    try:
        axes = json.loads(md["axes"])
    except ValueError:
        axes = [a.strip() for a in md["axes"].split(",") if a.strip()]
    if not (isinstance(axes, list) and axes and all(isinstance(a, str) and a for a in axes)
            and len(set(axes)) == len(axes)):
        warnings.append(f"metadata axes {md['axes']!r} is not a list of distinct names; taken from the blocks")
        return None
    return list(canonical_axes(axes))  # columns by name, in the fixed x, y, z order whatever the writer's order


def _decode_blocks(contents: McapContents, roles: dict[str, str], axes: list[str] | None,
                   warnings: list[str]) -> tuple[Blocks, list[str] | None, Counter[str]]:
    """Every block of each role's topic as ``(stamp_ns, block)``; the raw bytes are released topic by topic.

    Returns the decoded blocks, the axes (from the first block when ``axes`` is None) and the count of malformed
    blocks per role (the first one of each role is reported in ``warnings``).
    """
    decoded: Blocks = {}
    malformed: Counter[str] = Counter()
    for role, topic in roles.items():
        out = decoded[role] = []
        raws = contents.messages.pop(topic, [])
        for _, _, raw in raws:
            try:
                if axes is None:  # no metadata: the first block's field names, in the fixed x, y, z order
                    axes = list(canonical_axes(deserialize_block(raw)[2]))
                stamp, block, _names = deserialize_block(raw, axes)
            except ValueError as exc:
                if malformed[role] == 0:
                    warnings.append(f"{topic}: malformed block skipped ({exc})")
                malformed[role] += 1
                continue
            out.append((stamp, block))
        del raws
    return decoded, axes, malformed


def _sample_period(path: Any, md: dict[str, Any], decoded: Blocks, sample_rate: float | None,
                   warnings: list[str]) -> int:
    """The sample period [ns]: ``sample_rate`` if given, else the metadata's unless the block stamps contradict it,
    else inferred from the stamps."""
    def from_stamps() -> int | None:
        return _infer_dt_ns([[(s, len(b)) for s, b in blks] for blks in decoded.values()])

    if sample_rate is not None:
        try:
            return sample_period_ns(sample_rate)
        except ValueError as exc:
            raise ValueError(f"{path}: --sample-rate/sample_rate= {exc}") from None
    if "sample_rate" in md:
        try:
            dt_ns = sample_period_ns(float(md["sample_rate"]))
        except ValueError as exc:
            warnings.append(f"metadata sample_rate {md['sample_rate']!r} unusable ({exc}); inferred from stamps")
        else:  # the stamps are the contract's ground truth: a metadata rate they contradict is not used
            inferred = from_stamps()
            if inferred is not None and inferred != dt_ns:
                warnings.append(f"metadata sample_rate {md['sample_rate']!r} Hz contradicts the block stamps "
                                f"({1e9 / inferred:g} Hz: {inferred} ns per sample); the stamps are used")
                return inferred
            return dt_ns
    inferred = from_stamps()
    if inferred is None:
        raise ValueError(f"{path}: cannot infer the sample rate (fewer than two consecutive blocks, no "
                         "sample_rate metadata); pass sample_rate=")
    return inferred


def _run_origin(md: dict[str, Any], all_stamps: list[int], dt_ns: int, warnings: list[str]) -> int:
    """Stamp [ns] of sample index 0: the metadata's ``t0_ns`` when the stamps lie on its grid, else the first stamp."""
    t0_ns = None
    if "t0_ns" in md:
        try:
            t0_ns = int(md["t0_ns"])
        except ValueError:
            warnings.append(f"metadata t0_ns {md['t0_ns']!r} is not an integer; the first stamp is used")
    if t0_ns is not None:
        phases = Counter((s - t0_ns) % dt_ns for s in all_stamps)
        if phases.most_common(1)[0][0] != 0:  # most stamps off the metadata's grid: that t0 is not the stamps'
            warnings.append(f"metadata t0_ns {md['t0_ns']!r} is not on the block stamps' {dt_ns} ns grid; the "
                            "first stamp is used")
            t0_ns = None
    return min(all_stamps) if t0_ns is None else t0_ns


def _index_of(stamp: int, t0_ns: int, dt_ns: int) -> int:
    """Nearest sample index of ``stamp`` (off-grid stamps are rounded)."""
    q, r = divmod(stamp - t0_ns, dt_ns)
    return q + int(2 * r >= dt_ns)


def _place_role(blks: list[tuple[int, np.ndarray]], n_axes: int, length: int, k_first: int, t0_ns: int,
                dt_ns: int) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """One role's blocks placed by sample index into a NaN-filled ``(length, n_axes)`` array.

    Returns the array, the covered-sample mask and the role's bookkeeping (gaps, duplicates, conflicts, …; without
    the keys the caller adds).
    """
    arr = np.full((length, n_axes), np.nan)
    cov = np.zeros(length, dtype=bool)
    dup = conflicts = off_grid = 0
    seen_k0 = set()
    sizes: Counter[int] = Counter()
    for stamp, block in blks:
        q = _index_of(stamp, t0_ns, dt_ns)
        off_grid += int((stamp - t0_ns) % dt_ns != 0)
        a = int(q - k_first)
        b = a + len(block)
        sizes[len(block)] += 1
        if q in seen_k0 or cov[a:b].any():
            dup += 1
            if not np.array_equal(arr[a:b], block, equal_nan=True):
                conflicts += 1  # keep the first copy; a conflicting second one is reported
            continue
        seen_k0.add(q)
        arr[a:b] = block
        cov[a:b] = True
    idx = np.flatnonzero(cov)
    lo, hi = (int(idx[0]), int(idx[-1]) + 1) if idx.size else (0, 0)
    gaps = [(a + lo, b + lo) for a, b in _runs(~cov[lo:hi])]
    typical = sizes.most_common(1)[0][0] if sizes else 0
    missing = int(sum(b - a for a, b in gaps))
    info = {
        "count": len(blks), "block_sizes": sorted(sizes), "first_k": lo + k_first,
        "end_k": hi + k_first, "gaps": [(a + k_first, b + k_first) for a, b in gaps],
        "missing_samples": missing, "missing_blocks": int(np.ceil(missing / typical)) if typical else 0,
        "duplicates": dup, "conflicts": conflicts, "off_grid": off_grid,
    }
    return arr, cov, info


def _segments(markers: list[dict[str, Any]], k_offset: int, n: int, start: int,
              covered: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Experiment segments from the markers: each ends at the next marker (or its own ``k1``/``n``), with its rows in
    the trimmed arrays and whether every block topic covers it."""
    segments = []
    for i, m in enumerate(markers):
        k1 = markers[i + 1]["k0"] if i + 1 < len(markers) else k_offset + n
        if "k1" in m["info"]:
            k1 = min(k1, int(m["info"]["k1"]))
        elif "n" in m["info"]:
            k1 = min(k1, m["k0"] + int(m["info"]["n"]))
        s_row, e_row = max(m["k0"] - k_offset, 0), min(k1 - k_offset, n)
        complete = m["k0"] >= k_offset and k1 <= k_offset + n and e_row > s_row and all(
            covered[r][s_row + start:e_row + start].all() for r in covered)
        segments.append({"name": m["name"], "k0": m["k0"], "k1": int(k1), "start": int(s_row),
                         "stop": int(max(e_row, s_row)), "stages": m["stages"], "complete": bool(complete),
                         "info": m["info"]})
    return segments


class _Selected(NamedTuple):
    """What the scan of a recording found and which block topic plays which role."""

    contents: McapContents            #: the scan (raw messages still held)
    md: dict[str, Any]                #: the ``piezo_ff_ros`` metadata record ({} without one)
    roles: dict[str, str]             #: role → topic, for the block topics found (CDR only)
    topic_counts: dict[str, int]      #: messages per topic, counted before any is released


def _select_topics(path: str | Path, namespace: str | None, warnings: list[str]) -> _Selected:
    """Scan the recording and pick its block topic for each role.

    Parameters
    ----------
    path : str or Path
        ``.mcap`` file or rosbag2 directory.
    namespace : str or None
        The namespace of the topics, where the file holds several.
    warnings : list of str
        Appended to: truncation, topics with a non-CDR encoding.

    Returns
    -------
    _Selected

    Raises
    ------
    ValueError
        Not MCAP, nothing readable, no block topic, several candidates for a role.
    """
    contents = scan_mcap(path)
    if contents.truncated and contents.error:   # (scan_mcap sets both together)
        warnings.append(contents.error)
    non_cdr = {t: e for t, e in contents.encodings.items() if e != "cdr"}
    if non_cdr:
        warnings.append(f"topics with a non-CDR encoding ignored: {non_cdr}")
    md = contents.metadata_record()

    picked = {r: _pick_topic(contents, r, BLOCK_TYPE, namespace) for r in BLOCK_ROLES}
    roles = {r: t for r, t in picked.items() if t is not None and contents.encodings.get(t) == "cdr"}
    if not roles:
        raise ValueError(f"{path}: no block topic (reference/voltage/displacement of type {BLOCK_TYPE}); "
                         f"topics found: {contents.topics or 'none'}")
    topic_counts = {t: len(contents.messages.get(t, [])) for t in contents.topics}
    return _Selected(contents, md, roles, topic_counts)


class _Timeline(NamedTuple):
    """The decoded blocks of the main time span and the sample grid they lie on."""

    decoded: Blocks                   #: per role ``[(stamp_ns, block)]``; emptied by :func:`_place_blocks`
    outliers: Blocks                  #: per role, the blocks stamped outside the recording's span
    malformed: Counter[str]           #: undecodable blocks per role
    axes: list[str]                   #: axis names, in the fixed x, y, z order
    dt_ns: int                        #: sample period [ns]
    t0_ns: int                        #: stamp of sample index 0 [ns]


def _decode_on_grid(path: str | Path, sel: _Selected, sample_rate: float | None,
                    warnings: list[str]) -> _Timeline:
    """Decode every block, settle the sample period and origin, and set aside the blocks stamped off the span.

    Parameters
    ----------
    path : str or Path
        The recording (named in errors).
    sel : _Selected
        The scan; its block topics' raw messages are released as they are decoded.
    sample_rate : float or None
        Override [Hz].
    warnings : list of str
        Appended to (metadata axes/rate/t0 not usable, malformed blocks, outliers).

    Returns
    -------
    _Timeline

    Raises
    ------
    ValueError
        No decodable block; no usable sample rate.
    """
    decoded, axes, malformed = _decode_blocks(sel.contents, sel.roles, _metadata_axes(sel.md, warnings), warnings)
    if axes is None or not any(decoded.values()):
        raise ValueError(f"{path}: the block topics {sorted(sel.roles.values())} hold no decodable block")

    dt_ns = _sample_period(path, sel.md, decoded, sample_rate, warnings)
    # stamps far outside the span of the data (a clock glitch, a corrupt stamp) are set aside and reported: the
    # arrays are sized from the data, never from the stamp span
    decoded, outliers = _split_outliers(decoded, dt_ns)
    for role, outs in outliers.items():
        if outs:
            warnings.append(f"{sel.roles[role]}: {len(outs)} block(s) stamped outside the recording's span ignored "
                            f"(stamps {[s for s, _ in outs[:5]]} ns{' …' if len(outs) > 5 else ''})")
    all_stamps = [s for blks in decoded.values() for s, _ in blks]
    t0_ns = _run_origin(sel.md, all_stamps, dt_ns, warnings)
    return _Timeline(decoded, outliers, malformed, axes, dt_ns, t0_ns)


class _Placed(NamedTuple):
    """Every role's blocks placed by sample index, over the span from the first block to the end of the last."""

    arrays: dict[str, np.ndarray]         #: per role, ``(length, n_axes)``, NaN where no block
    covered: dict[str, np.ndarray]        #: per role, the samples a block covers
    info: dict[str, dict[str, Any]]       #: per role, the bookkeeping of ``meta['blocks']``
    k_first: int                          #: sample index of array row 0
    length: int                           #: rows


def _place_blocks(tl: _Timeline, roles: dict[str, str], warnings: list[str]) -> _Placed:
    """Place each role's blocks into its array, releasing the decoded blocks role by role.

    Parameters
    ----------
    tl : _Timeline
        The decoded blocks (``tl.decoded`` is emptied) and the sample grid.
    roles : dict
        Role → topic (named in the bookkeeping and warnings).
    warnings : list of str
        Appended to: block stamps off the sample grid.

    Returns
    -------
    _Placed
    """
    dt_ns, t0_ns, decoded = tl.dt_ns, tl.t0_ns, tl.decoded
    k_first = min(_index_of(s, t0_ns, dt_ns) for blks in decoded.values() for s, _ in blks)
    k_end = max(_index_of(s, t0_ns, dt_ns) + len(b) for blks in decoded.values() for s, b in blks)
    length = int(k_end - k_first)
    arrays, covered, info = {}, {}, {}
    for role in list(decoded):
        blks = decoded.pop(role)  # placed below: each role's decoded blocks are released once in its array
        arrays[role], covered[role], placed = _place_role(blks, len(tl.axes), length, k_first, t0_ns, dt_ns)
        info[role] = {
            "topic": roles[role], **placed, "malformed": tl.malformed[role],
            "outliers": len(tl.outliers.get(role, [])),
            "outlier_stamps_ns": [int(st) for st, _ in tl.outliers.get(role, [])[:MAX_LISTED_RANGES]],
        }
        if placed["off_grid"]:
            warnings.append(f"{roles[role]}: {placed['off_grid']} block stamps off the {dt_ns} ns sample grid "
                            "(rounded)")
    return _Placed(arrays, covered, info, k_first, length)


class _Span(NamedTuple):
    """The rows of the placed arrays that the run keeps."""

    start: int                        #: first row kept
    stop: int                         #: one past the last row kept
    k_offset: int                     #: run index of the first row kept
    n: int                            #: rows kept


def _common_span(placed: _Placed, trim: bool, path: str | Path) -> _Span:
    """All rows, or with ``trim`` the rows where every recorded block topic has started and not yet ended.

    Parameters
    ----------
    placed : _Placed
        The placed arrays and their bookkeeping.
    trim : bool
        Keep only the common span.
    path : str or Path
        The recording (named in the error).

    Returns
    -------
    _Span

    Raises
    ------
    ValueError
        With ``trim``: the block topics do not overlap in time.
    """
    start, stop = 0, placed.length
    if trim:
        present = [i for i in placed.info.values() if i["count"] > 0]
        start = max(i["first_k"] for i in present) - placed.k_first
        stop = min(i["end_k"] for i in present) - placed.k_first
        if stop <= start:
            raise ValueError(f"{path}: the block topics do not overlap in time "
                             f"({ {r: (i['first_k'], i['end_k']) for r, i in placed.info.items()} })")
    return _Span(start, stop, int(start + placed.k_first), int(stop - start))


def _role_rows(placed: _Placed, role: str, span: _Span, n_axes: int, warnings: list[str]) -> np.ndarray:
    """The kept rows of a role's array, or NaN (with a warning) when the recording has no such topic.

    Parameters
    ----------
    placed : _Placed
        The placed arrays.
    role : {'voltage', 'displacement'}
        The role.
    span : _Span
        The rows kept.
    n_axes : int
        Columns of the NaN stand-in.
    warnings : list of str
        Appended to when the topic is absent.

    Returns
    -------
    ndarray
        ``(span.n, n_axes)``.
    """
    if role in placed.arrays:
        return placed.arrays[role][span.start:span.stop]
    warnings.append(f"no {role} topic: {'u' if role == 'voltage' else 'y'} is NaN")
    return np.full((span.n, n_axes), np.nan)


def _experiment_segments(contents: McapContents, namespace: str | None, tl: _Timeline, span: _Span,
                         covered: dict[str, np.ndarray], warnings: list[str]) -> list[dict[str, Any]]:
    """The experiment segments of the recording's marker topic (none without one).

    Parameters
    ----------
    contents : McapContents
        The scan.
    namespace : str or None
        The namespace of the topics.
    tl : _Timeline
        The sample grid.
    span : _Span
        The rows kept.
    covered : dict
        Per role, the samples a block covers.
    warnings : list of str
        Appended to: markers skipped.

    Returns
    -------
    list of dict
        ``meta['segments']``.
    """
    exp_topic = _pick_topic(contents, "experiment", EXPERIMENT_TYPE, namespace)
    markers = _experiment_markers(contents.messages.get(exp_topic, []), tl.t0_ns, tl.dt_ns, warnings) \
        if exp_topic else []
    return _segments(markers, span.k_offset, span.n, span.start, covered)


def _run_meta(path: str | Path, sel: _Selected, tl: _Timeline, placed: _Placed, span: _Span,
              segments: list[dict[str, Any]], warnings: list[str]) -> dict[str, Any]:
    """``RunData.meta`` of :func:`read_run` (the diagnostics summary is read here).

    Parameters
    ----------
    path : str or Path
        The recording.
    sel, tl, placed, span
        The steps' results.
    segments : list of dict
        The experiment segments.
    warnings : list of str
        Every warning of the read (the list itself is stored).

    Returns
    -------
    dict
    """
    contents = sel.contents
    diag_topic = next((t for t, tn in contents.topics.items() if tn == DIAGNOSTICS_TYPE
                       and t.rstrip("/").split("/")[-1] == "diagnostics"), None)
    diagnostics = _diagnostics_summary(contents.messages.get(diag_topic, [])) if diag_topic else {"messages": 0}
    return {
        "source": str(path), "format": "rosbag2" if Path(path).is_dir() else "mcap", "profile": contents.profile,
        "library": contents.library, "truncated": contents.truncated, "truncation_error": contents.error,
        "topics": {t: {"type": tn, "count": sel.topic_counts.get(t, 0)} for t, tn in contents.topics.items()},
        "sample_rate": 1e9 / tl.dt_ns, "dt_ns": int(tl.dt_ns), "t0_ns": int(tl.t0_ns), "k_offset": span.k_offset,
        "axes": tuple(tl.axes), "blocks": placed.info, "segments": segments, "metadata": sel.md,
        "diagnostics": diagnostics, "warnings": warnings,
        "trimmed": {"head": int(span.start), "tail": int(placed.length - span.stop)}, "loss": contents.loss_summary(),
    }


def read_run(path: str | Path, *, namespace: str | None = None, sample_rate: float | None = None,
             trim: bool = True) -> RunData:
    """Reassemble a ROS 2 recording of the topic contract into a sample-aligned :class:`RunData`.

    Parameters
    ----------
    path
        ``.mcap`` file (ours or any ROS 2 MCAP writer's) or rosbag2 directory.
    namespace
        Pick ``/<namespace>/reference`` … when the file holds several namespaces.
    sample_rate
        Override [Hz]; default from the ``piezo_ff_ros`` metadata record, else inferred from the block stamps.
    trim
        Keep only the span where every recorded block topic has started and not yet ended (the recorder starts
        and stops between topics); interior gaps stay NaN.

    Returns
    -------
    RunData
        ``t`` [s] = sample index / fs (index 0 = ``t0_ns``), ``u`` [V], ``y`` [m], ``reference`` [m] or None;
        NaN where a topic is absent or has a gap.  ``meta`` holds: ``source``, ``truncated``/``truncation_error``,
        ``topics`` (type and count), ``sample_rate``, ``dt_ns``, ``t0_ns``, ``k_offset`` (run index of array
        row 0), ``blocks`` (per role: topic, count, block sizes, ``gaps`` [(k_start, k_stop)] in run indices,
        ``missing_samples``, ``missing_blocks``, ``duplicates``, ``conflicts``, ``off_grid``, ``malformed``),
        ``segments`` (experiment markers: name, k0, k1, start/stop array rows, stages, ``complete``),
        ``metadata`` (the ``piezo_ff_ros`` record), ``diagnostics`` (counts and last status values per name),
        ``warnings``.

    Raises
    ------
    ValueError
        Not MCAP, nothing readable, no block topic, inconsistent axes, no overlapping data.
    """
    warnings: list[str] = []
    sel = _select_topics(path, namespace, warnings)
    tl = _decode_on_grid(path, sel, sample_rate, warnings)
    placed = _place_blocks(tl, sel.roles, warnings)
    span = _common_span(placed, trim, path)
    t = (np.arange(span.n, dtype=np.int64) + span.k_offset) * (tl.dt_ns / 1e9)
    u = _role_rows(placed, "voltage", span, len(tl.axes), warnings)
    y = _role_rows(placed, "displacement", span, len(tl.axes), warnings)
    ref = placed.arrays["reference"][span.start:span.stop] if "reference" in placed.arrays else None
    segments = _experiment_segments(sel.contents, namespace, tl, span, placed.covered, warnings)
    meta = _run_meta(path, sel, tl, placed, span, segments, warnings)
    return RunData(t=t, u=u, y=y, axes=tuple(tl.axes), reference=ref, meta=meta)
