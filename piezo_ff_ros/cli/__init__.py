"""``piezo-ff``: one command, one module per subcommand (``piezo_ff_ros/cli/<name>.py``).

Each subcommand module defines ``add_parser(subparsers)`` (registering itself, with ``set_defaults(func=run)``) and
``run(args) -> int``.  Modules are imported only when listed in :data:`SUBCOMMANDS`, and a failure to import one
(e.g. rclpy absent for ``demo``) only disables that subcommand.

Errors are handled here, once, for every subcommand: bad input (:class:`CliError`, ``ValueError`` — which includes
``ConfigError`` —, ``OSError`` such as an output path that is a directory, an H∞ synthesis that the config makes
infeasible) is one line ``piezo-ff CMD: error: …`` on stderr and exit code 2; anything else is a defect, reported
as one line ``piezo-ff CMD: internal error: …`` with exit code 1 (``PIEZO_FF_TRACEBACK=1`` shows the traceback).
A command never prints a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path
from typing import Sequence

SUBCOMMANDS = ["reproduce", "demo", "analyze", "identify", "commission", "diagnose", "bench", "check",
               "rig_check", "feedforward"]

#: later subcommands, one statement each, so that parallel additions merge without conflicts
SUBCOMMANDS += ["recover"]
SUBCOMMANDS += ["track"]
SUBCOMMANDS += ["play"]
SUBCOMMANDS += ["hold", "param", "echo", "lifecycle"]   # ROS helpers where the ros2 CLI is absent (pip wheels)

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1


class CliError(Exception):
    """Bad input to a command (an option, a path, a file's content).

    The message names what is wrong (the option, file, field or row); :func:`main` prints it as one line and
    exits with code 2.
    """


def output_file(path: str | Path, option: str, *, overwrite: bool = True) -> Path:
    """Check, before any long computation, that ``path`` can be written as a file; return it as a ``Path``.

    Raises :class:`CliError` naming ``option`` when ``path`` is a directory, exists and ``overwrite`` is false,
    or lies under a file or an unwritable directory.  Missing parent directories are fine (commands create them).
    """
    p = Path(path)
    if p.is_dir():
        raise CliError(f"{option} {p}: is a directory, not a file; give a file name")
    if p.exists() and not overwrite:
        raise CliError(f"{option} {p}: already exists; choose another name or pass --force")
    _check_parent(p, option)
    return p


def output_dir(path: str | Path, option: str) -> Path:
    """Check that ``path`` is a directory or can be created as one; return it as a ``Path``."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise CliError(f"{option} {p}: exists and is not a directory; give a directory")
    _check_parent(p, option)
    return p


def _check_parent(p: Path, option: str) -> None:
    anc = p.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if anc.exists() and not anc.is_dir():
        raise CliError(f"{option} {p}: {anc} is a file, not a directory")
    if anc.exists() and not os.access(anc, os.W_OK | os.X_OK):
        raise CliError(f"{option} {p}: directory {anc} is not writable")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``piezo-ff`` parser with every subcommand, or with ``only`` that one when it is a known subcommand (a
    command line naming its subcommand first needs no other module: each costs its imports, ~1 s for all)."""
    parser = argparse.ArgumentParser(
        prog="piezo-ff",
        description="Sensorless multivariable feedforward compensation of piezoelectric positioners "
                    "(Habineza et al., IEEE TASE 2018).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in [only] if only in SUBCOMMANDS else SUBCOMMANDS:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ImportError as exc:  # pragma: no cover - optional subcommands
            p = sub.add_parser(name, help=f"(unavailable: {exc})")
            p.set_defaults(func=lambda args, _e=exc, _n=name: _unavailable(_n, _e))
            continue
        mod.add_parser(sub)
    return parser


def _unavailable(name: str, exc: BaseException) -> int:
    print(f"piezo-ff {name}: unavailable here ({exc})", file=sys.stderr)
    return 2


#: options that name an output file / an output directory in every command that has them
OUTPUT_FILE_OPTIONS = ("json", "apply")
OUTPUT_DIR_OPTIONS = ("plots", "report")


def _check_output_options(args: argparse.Namespace) -> None:
    """Refuse unusable output paths before a command starts its work (not after minutes of computation)."""
    for name in OUTPUT_FILE_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value != "-":
            output_file(value, f"--{name}")
    for name in OUTPUT_DIR_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str):
            output_dir(value, f"--{name}")


def is_input_error(exc: BaseException) -> bool:
    """Whether ``exc`` reports bad input (one-line error, exit 2) rather than a defect."""
    if isinstance(exc, (CliError, ValueError, OSError)):
        return True
    hinf = sys.modules.get("piezo_ff_ros.core.synthesis.hinf")  # only raised once that module is in use
    return hinf is not None and isinstance(exc, hinf.HinfSynthesisError)


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (an ``OSError`` as ``path: reason``)."""
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename is not None else ""
        text = f"{where}{exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(part.strip() for part in text.splitlines() if part.strip())


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``piezo-ff`` with ``argv`` (default: the process's); the exit code (0 ok, 2 bad input, 1 defect)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # `rig-check` is the module rig_check (`rig_check` is no command: the full parser says so, listing them all)
    first = argv[0].replace("-", "_") if argv and "_" not in argv[0] else None
    parser = build_parser(first) if first in SUBCOMMANDS else build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _check_output_options(args)
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # noqa: BLE001 - the one place where every command's errors become one line
        if is_input_error(exc):
            print(f"piezo-ff {args.command}: error: {one_line(exc)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        if os.environ.get("PIEZO_FF_TRACEBACK"):
            raise
        print(f"piezo-ff {args.command}: internal error: {type(exc).__name__}: {one_line(exc)} (a defect; "
              "PIEZO_FF_TRACEBACK=1 shows the traceback)", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
