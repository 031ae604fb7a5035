"""``ctxmatch cache``: how much each part of the cache takes; ``ctxmatch cache clear``: remove parts of it, or
what is older than an age (:mod:`ctxmatch_lib.cache`)."""

from __future__ import annotations

import argparse

from . import error

DESCRIPTION = """\
Show the cache folder ($CTXMATCH_CACHE, else $XDG_CACHE_HOME/ctxmatch or ~/.cache/ctxmatch) and the size of each
of its parts; 'ctxmatch cache clear' removes parts of it. Everything in the cache is recomputed on demand.
Clearing never follows a link (a link is removed as a link, its target untouched), never leaves the cache
folder, and refuses a folder that holds no ctxmatch marker (CACHEDIR.TAG) and more than the cache's own
sub-folders. Temporary files younger than an hour are kept: a running process may be writing them."""

CLEAR_DESCRIPTION = """\
Remove the named parts of the cache (or --all), or only their files not modified for --older-than; with
--older-than and no part, every part. The parts' own folders stay, emptied. Exit status: 0 done, 2 a bad
argument, 1 a cache folder refused (no ctxmatch marker, and more than the cache's own sub-folders)."""

EXAMPLE = """\
examples:
  ctxmatch cache                                   # size per part
  ctxmatch cache clear sweeps evaluations          # the evaluation engine's cache
  ctxmatch cache clear --older-than 30d            # every part: files not modified for 30 days
  ctxmatch cache clear --all --dry-run             # what clearing everything would remove
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    from ..cache import CACHE_PARTS

    parser = subparsers.add_parser(
        "cache", help="show the cache's size per part; 'cache clear' removes parts or old files",
        description=DESCRIPTION, epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="cache_command")
    p = sub.add_parser(
        "clear", help="remove parts of the cache, or their files older than an age",
        description=CLEAR_DESCRIPTION, epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("parts", nargs="*", metavar="PART", help=f"parts to clear: {', '.join(CACHE_PARTS)}")
    p.add_argument("--all", action="store_true", help="every part: the whole cache but its marker")
    p.add_argument("--older-than", metavar="AGE",
                   help="only files not modified for AGE: a number and a unit, s, m, h, d or w (30m, 12h, 7d)")
    p.add_argument("--dry-run", action="store_true", help="print what would be removed; remove nothing")
    p.set_defaults(func=_clear)
    parser.set_defaults(func=_show)
    return parser


def _size(n: int) -> str:
    """Bytes for people: ``"0 B"``, ``"532 B"``, ``"12.3 MB"`` (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB" and n < 1000**4:
            return f"{n} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def _folders(folders: tuple[str, ...]) -> str:
    """``" (datasets/, data/)"``; folders under one parent as ``sweep/{candidates,overlap}/``."""
    if not folders:
        return ""
    parents = {f.rpartition("/")[0] for f in folders}
    if len(folders) > 1 and len(parents) == 1 and "" not in parents:
        return f" ({parents.pop()}/{{{','.join(f.rpartition('/')[2] for f in folders)}}}/)"
    return f" ({', '.join(f + '/' for f in folders)})"


def _files(n: int) -> str:
    return f"{n} file" if n == 1 else f"{n} files"


def _show(args) -> int:
    from ..cache import cache_usage

    usage = cache_usage()
    if not usage.exists:
        print(f"cache: {usage.root} (does not exist yet: nothing is cached)")
        return 0
    print(f"cache: {usage.root}")
    print(f"{'part':<12} {'size':>9} {'files':>7}  contents (folders)")
    for p in usage.parts:
        print(f"{p.name:<12} {_size(p.bytes):>9} {p.files:>7}  {p.description}{_folders(p.folders)}")
    print(f"{'total':<12} {_size(usage.bytes):>9} {usage.files:>7}")
    if not usage.clearable:
        print("note: this folder holds no ctxmatch marker (CACHEDIR.TAG) and more than the cache's own "
              "sub-folders: 'ctxmatch cache clear' refuses to delete in it")
    else:
        print("clear with: ctxmatch cache clear PART ... | --all [--older-than AGE] [--dry-run]")
    return 0


def _clear(args) -> int:
    from ..cache import CACHE_PARTS, clear_cache, parse_age

    unknown = [p for p in args.parts if p not in CACHE_PARTS]
    if unknown:
        return error("cache clear", f"unknown part {unknown[0]!r}: the parts are {', '.join(CACHE_PARTS)}")
    if args.all and args.parts:
        return error("cache clear", "give parts or --all, not both")
    if args.older_than is not None:
        try:
            parse_age(args.older_than)
        except ValueError as exc:
            return error("cache clear", "--older-than" + str(exc).removeprefix("older_than"))
    if not args.parts and not args.all and args.older_than is None:
        return error("cache clear",
                     f"name the parts to clear ({', '.join(CACHE_PARTS)}), or --all, or --older-than AGE")
    try:
        result = clear_cache(args.parts or "all", older_than=args.older_than, dry_run=args.dry_run)
    except ValueError as exc:  # a folder that is not the cache: refused
        return error("cache clear", str(exc), status=1)
    verb = "would remove" if args.dry_run else "removed"
    age = f", files not modified for {args.older_than}" if args.older_than else ""
    print(f"{verb} {_size(result.bytes)} in {_files(result.files)} from {result.root}{age}"
          + (" (dry run: nothing removed)" if args.dry_run else ""))
    for p in result.removed:
        if p.files:
            print(f"  {p.name:<12} {_size(p.bytes):>9}  {_files(p.files)}")
    if result.kept_in_progress:
        print(f"kept {_files(result.kept_in_progress)} being written (temporary, younger than an hour)")
    for rel in result.skipped:
        print(f"skipped {rel}/: on another file system (a mount point), never cleared")
    return 0
