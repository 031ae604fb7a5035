"""``ctxmatch data``: list the datasets, generate the embedded one, download the public ones, e.g.
``ctxmatch data download hpatches --root ~/data/ctxmatch`` or ``ctxmatch data strecha --scenes fountain-P11``."""

from __future__ import annotations

import argparse
import re

from . import error


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "data", help="list, generate or download datasets",
        description="List the datasets, generate the embedded default, download the public real datasets.",
    )
    sub = parser.add_subparsers(dest="data_command", required=True)

    p = sub.add_parser("list", help="registered dataset names and whether their files are present")
    p.add_argument("--root", help="data root of the real datasets (default: $CTXMATCH_DATA)")
    p.set_defaults(func=_list)

    p = sub.add_parser("embedded", help="generate the embedded default dataset into the cache (if needed)")
    p.add_argument("--root", help="parent folder (default: the datasets cache)")
    p.set_defaults(func=_embedded)

    from ..datasets.download import download_names

    p = sub.add_parser(
        "download", help="download a public dataset (pooch, pinned SHA-256)",
        description="Download and unpack a public dataset under the data root, checking its SHA-256.",
    )
    p.add_argument("name", choices=download_names())
    p.add_argument("--root", help="data root to fill (default: $CTXMATCH_DATA, else the cache)")
    p.add_argument("--url", help="archive URL override (http, https, ftp or file://); single-archive datasets")
    p.add_argument("--sha256", help="expected SHA-256 of the archive (required with an unpinned --url)")
    p.add_argument("--allow-unpinned", action="store_true",
                   help="accept an archive with no pinned hash and print its SHA-256")
    p.add_argument("--force", action="store_true", help="replace a dataset folder that already exists")
    p.add_argument("--progress", action="store_true", help="show a progress bar")
    p.set_defaults(func=_download)

    from ..datasets.strecha import STRECHA_SCENES

    p = sub.add_parser(
        "strecha", help="download the six calibrated Strecha scenes (pinned commit, SHA-256 per file)",
        description="Download the Strecha scenes from openMVG/SfM_quality_evaluation at a pinned commit into "
                    "<root>/calibrated/strecha/<scene>, checking every file against its pinned SHA-256.",
    )
    p.add_argument("--root", help="data root to fill (default: $CTXMATCH_DATA, else the cache)")
    p.add_argument("--scenes", nargs="+", choices=STRECHA_SCENES, metavar="SCENE",
                   help=f"scenes to fetch (default: all six: {', '.join(STRECHA_SCENES)})")
    p.add_argument("--url", help="base URL of a mirror of Benchmarking_Camera_Calibration_2008 (http, https, "
                                 "ftp or file://); every file is still checked against its pinned hash")
    p.add_argument("--force", action="store_true", help="replace a scene folder that already exists")
    p.add_argument("--progress", action="store_true", help="show a progress bar")
    p.set_defaults(func=_strecha, sha256=None, allow_unpinned=False)

    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    return parser


def _list(args) -> int:
    from ..datasets import list_datasets, load_dataset

    for name in list_datasets():
        if name.startswith("embedded"):
            status = "offline (generated into the cache on first use)"
        else:
            try:
                status = f"{len(load_dataset(name, root=args.root))} pairs"
            except (FileNotFoundError, ValueError) as exc:
                status = f"not available: {exc}"
        print(f"{name:20s} {status}")
    return 0


def _check_root(args) -> str | None:
    """``--root`` as a folder that can be filled, checked before any work; the error, or ``None``."""
    from ..cache import check_writable

    try:
        if args.root is not None:
            check_writable(args.root, "--root", folder=True)
    except ValueError as exc:
        return str(exc)
    return None


def _embedded(args) -> int:
    from ..datasets import load_dataset

    problem = _check_root(args)
    if problem:
        return error("data embedded", problem)
    ds = load_dataset("embedded", root=args.root)
    print(f"{ds!r} at {ds.root}")
    return 0


def _strecha(args) -> int:
    """Each scene in turn (the group ``strecha`` when all six); a mirror's base URL holds the scene folders."""
    if not args.scenes:
        return _download(_with(args, name="strecha"), command="strecha")
    for scene in args.scenes:
        url = args.url and f"{args.url.rstrip('/')}/{scene}"
        code = _download(_with(args, name=f"strecha-{scene}", url=url), command="strecha")
        if code:
            return code
    return 0


def _with(args, **changes):
    return argparse.Namespace(**{**vars(args), **changes})


def _download(args, command: str = "download") -> int:
    from ..datasets.download import download_dataset

    problem = _check_root(args)
    if args.sha256 is not None and not re.fullmatch(r"[0-9a-fA-F]{64}", args.sha256):
        problem = f"--sha256 must be 64 hexadecimal digits, got {args.sha256!r}"
    if args.url is not None and not re.match(r"(https?|ftp|file)://", args.url):
        problem = f"--url must start with http://, https://, ftp:// or file://, got {args.url!r}"
    if problem:
        return error(f"data {command}", problem)
    try:
        paths = download_dataset(
            args.name, root=args.root, url=args.url, sha256=args.sha256, allow_unpinned=args.allow_unpinned,
            force=args.force, progress=args.progress,
        )
    except (ValueError, OSError) as exc:  # OSError: also the network errors (requests' derive from it)
        return error(f"data {command}", str(exc), status=1)
    for p in paths:
        print(p)
    return 0
