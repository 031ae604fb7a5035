"""The ``ctxmatch`` command line.

Each sub-command lives in a module of this package exposing ``add_parser(subparsers)``; the module sets
``func`` on its parser. Heavy imports happen inside the command, so ``ctxmatch --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Sub-command modules, in the order shown by --help.
_COMMANDS = ["match", "eval", "sweep", "figures", "data", "train"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ctxmatch",
        description="SIFT Matching by Context Exposed: blob matching, DTM and the benchmark.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"ctxmatch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in _COMMANDS:
        importlib.import_module(f"{__name__}.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
