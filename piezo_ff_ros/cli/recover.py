"""``piezo-ff recover RUN.mcap [--out FIXED.mcap] [--force]``: rewrite a damaged recording as a complete MCAP file.

A recorder killed with SIGKILL (or a full disk, a power cut) leaves a file without summary and footer that only
our reader opens; a corrupt chunk makes readers stop there.  This reads every record that survives, skipping
corrupt chunks, and writes a complete file (indexes, statistics, summary, footer) that ``mcap``, ``rosbags``,
``ros2 bag`` and Foxglove open.  It prints what was lost: chunks, messages (per topic), log-time ranges.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import CliError, output_file


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("recover", help="rewrite a damaged/killed recording as a complete MCAP file",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("run_path", metavar="RUN.mcap", help="the damaged MCAP file")
    p.add_argument("--out", metavar="FIXED.mcap", help="output file (default: RUN.recovered.mcap next to the input)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--json", metavar="FILE", help="write the recovery report as JSON ('-' = stdout)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..core.recording.recover import recover_mcap

    src = Path(args.run_path)
    if not src.exists():
        raise FileNotFoundError(f"{src}: no such file")
    if src.is_dir():
        raise CliError(f"{src}: is a directory; give the .mcap file to recover")
    dst = Path(args.out) if args.out else src.with_name(src.stem + ".recovered.mcap")
    if dst.resolve() == src.resolve():
        raise CliError(f"--out {dst}: the output would overwrite the input")
    output_file(dst, "--out", overwrite=args.force)
    if args.json and args.json != "-":
        output_file(args.json, "--json")
    report = recover_mcap(src, dst)
    lost = report["chunks_lost"]
    lines = [f"recovered {report['messages_written']} message(s) on {report['channels']} channel(s) "
             f"({report['metadata_records']} metadata record(s)) → {dst}"]
    if not report["footer"]:
        lines.append("  the input had no footer/summary (a writer that was killed or a file cut short)")
    if lost or report["bytes_skipped"] or report["orphan_messages"]:
        lines.append(f"  lost: {lost} of {report['chunks_total']} chunk(s), ≥ {report['messages_lost']} message(s) "
                     f"{report.get('messages_lost_by_topic') or ''}, {report['bytes_skipped']} byte(s) skipped, "
                     f"{report['orphan_messages']} message(s) without a channel definition")
        for t0, t1 in report["lost_time_ranges_ns"][:10]:
            lines.append(f"  lost log-time range [{t0}, {t1}] ns ({(t1 - t0) / 1e9:.3f} s)")
    else:
        lines.append("  nothing lost")
    if args.json == "-":
        print(json.dumps(report, indent=2, default=str))
    else:
        print("\n".join(lines))
        if args.json:
            Path(args.json).write_text(json.dumps(report, indent=2, default=str) + "\n")
    return 0
