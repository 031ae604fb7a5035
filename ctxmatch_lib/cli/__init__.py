"""The ``ctxmatch`` command line: one module per sub-command with ``add_parser(subparsers)`` setting ``func``;
heavy imports happen inside the command, so ``ctxmatch --help`` is instant."""

from __future__ import annotations

import argparse
import importlib
import sys

# Sub-command modules, in the order shown by --help.
_COMMANDS = ["match", "eval", "sweep", "figures", "data", "train", "cache", "warmup"]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``ctxmatch`` parser: every sub-command, or only ``command`` (what a run of it needs: the other
    sub-commands' modules are not imported)."""
    parser = argparse.ArgumentParser(
        prog="ctxmatch",
        description="SIFT Matching by Context Exposed: blob matching, DTM and the benchmark.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"ctxmatch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in _COMMANDS if command not in _COMMANDS else [command]:
        importlib.import_module(f"{__name__}.{name}").add_parser(sub)
    return parser


#: Exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130


def error(command: str, msg: str, status: int = 2) -> int:
    """Print ``ctxmatch <command>: error: msg`` on stderr and return ``status`` (2: a bad argument)."""
    print(f"ctxmatch {command}: error: {msg}", file=sys.stderr)
    return status


def main(argv: list[str] | None = None) -> int:
    """Run one ``ctxmatch`` command and return its exit status; Ctrl-C gives one line and status 130 (results
    are written atomically, so a rerun resumes)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(first).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        sys.stderr.write(f"\nctxmatch {args.command}: interrupted; rerun the same command to resume (finished "
                         "work is kept, nothing half-written)\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
