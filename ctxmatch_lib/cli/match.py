"""``ctxmatch match``: two image files (or an hloc pairs list) to filtered matches, a picture and exports."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import error

DESCRIPTION = """\
Match two images with the paper's pipeline: SIFT features -> blob matching (Sec. 3) -> spatial filter(s)
(DTM by default, Sec. 4) -> optional model step (1SAC, Sec. 5.1, or OpenCV's USAC: ransac, prosac, magsac).
Image sizes are read from the images. --out writes an .npz with kpts1, kpts2 ((N, 2) x, y pixels, origin at
the centre of the top-left pixel), shapes1, shapes2, matches ((K, 2) int64 rows into kpts1/kpts2), scores
((K,), lower is better), image_size1, image_size2 (width, height) and settings (JSON). --plot draws the kept
matches.

Folder mode: --pairs pairs.txt --images DIR (one "name1 name2" per line, hloc's convention) writes one .npz
per pair into --out (a folder); it is resumable: finished pairs are skipped on a re-run, a killed run
loses nothing written. --export-h5 DIR writes hloc's features.h5 and matches.h5 there; --export-colmap DB
writes the keypoints and matches into a COLMAP database."""

EXAMPLE = """\
examples:
  ctxmatch match img1.jpg img2.jpg --out matches.npz --plot matches.png
  ctxmatch match img1.jpg img2.jpg --filter dtm --filter adalam --model 1sac --model-kind H
  ctxmatch match img1.jpg img2.jpg --blob "paper-best:t_o=none" --features sift --max-keypoints 4000
  ctxmatch match --pairs pairs.txt --images images/ --out matches/ --export-h5 hloc/ --export-colmap db.db
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "match",
        help="match two images (or an hloc pairs list): features, blob matching, DTM; npz, plot, hloc/COLMAP exports",
        description=DESCRIPTION,
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("images_pair", nargs="*", metavar="IMAGE", help="the two images (omit with --pairs)")
    p.add_argument("--pairs", default=None, help="hloc pairs file: one 'name1 name2' per line (folder mode)")
    p.add_argument("--images", default=None, help="folder the names of --pairs are relative to")
    p.add_argument("--out", default=None,
                   help="output .npz (default: matches.npz); in folder mode a folder (default: matches/)")
    p.add_argument("--plot", default=None,
                   help="picture of the kept matches (.png, .pdf, ...); in folder mode a folder of pictures")
    p.add_argument("--features", default="sift-rootsift",
                   help="feature preset: sift-rootsift (default), sift-rootsift-upright, sift")
    p.add_argument("--max-keypoints", type=int, default=None, help="keypoints per image (default: the preset's, 8000)")
    p.add_argument("--blob", default="paper-best",
                   help="blob preset (paper-best, paper-best-overlap, baseline), optionally with overrides "
                        "'NAME:key=value,...' or just 'key=value,...' (keys: f, prefilter, f_prime, ratio, t_o, "
                        "t_o_kind, combine) (default: paper-best)")
    p.add_argument("--filter", action="append", default=None, dest="filters",
                   help="spatial filter, repeatable or comma-separated, applied in order; 'none' for the blob "
                        "candidates (default: dtm)")
    p.add_argument("--model", default="none", choices=["none", "1sac", "ransac", "prosac", "magsac", "poselib"],
                   help="model step on the filtered matches: 1sac (the paper's), ransac (USAC_MAGSAC, 3 px), prosac "
                        "(the same with PROSAC sampling by score), magsac (USAC_MAGSAC with fb82/MiHo's 1 px, "
                        "0.9999, 100000), poselib (PoseLib's LO-RANSAC, the same settings) (default: none)")
    p.add_argument("--model-kind", default="F", choices=["F", "H"],
                   help="F (any scene, default) or H (planar scene, pure rotation)")
    p.add_argument("--model-threshold", type=float, default=None, help="model step threshold in px (default: 15)")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default: 0)")
    p.add_argument("--export-h5", default=None, metavar="DIR",
                   help="write hloc's features.h5 and matches.h5 into DIR (needs h5py: pip install 'ctxmatch[export]')")
    p.add_argument("--export-colmap", default=None, metavar="DB",
                   help="write cameras, images, keypoints and matches into the COLMAP database DB (created if absent)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the feature cache")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar (folder mode)")
    p.set_defaults(func=run)
    return p


def _check_plot_suffix(path) -> None:
    suffix = Path(path).suffix.lower().lstrip(".")
    if not suffix:
        return  # written as PNG
    from matplotlib.backend_bases import FigureCanvasBase

    known = FigureCanvasBase.get_supported_filetypes()
    if suffix not in known:
        raise ValueError(f"--plot: unknown picture format {'.' + suffix!r}; use one of "
                         f"{', '.join('.' + k for k in sorted(known))}")


def _check_inputs_and_outputs(args, folder: bool) -> None:
    """Every input and output path, before any work: a bad one fails at once, naming its flag."""
    from ..cache import check_writable
    from ..io.export import check_export_paths

    if folder:
        pairs = Path(args.pairs)
        if not pairs.exists():
            raise ValueError(f"--pairs: file not found: {pairs}")
        if not pairs.is_file():
            raise ValueError(f"--pairs: {pairs} is not a file")
        if not Path(args.images).is_dir():
            raise ValueError(f"--images: folder not found: {args.images}")
        out = Path(args.out or "matches")
        if out.suffix.lower() == ".npz":
            raise ValueError(f"--out: in folder mode --out is a folder, got {out}")
        check_writable(out, "--out", folder=True)
        if args.plot:
            check_writable(args.plot, "--plot", folder=True)
    else:
        for image in args.images_pair:
            if not Path(image).exists():
                raise ValueError(f"IMAGE: file not found: {image}")
            if not Path(image).is_file():
                raise ValueError(f"IMAGE: {image} is not a file")
        out = Path(args.out or "matches.npz")
        if out.suffix.lower() != ".npz":
            raise ValueError(f"--out must end with .npz, got {out}")
        check_writable(out, "--out")
        if args.plot:
            _check_plot_suffix(args.plot)
            check_writable(args.plot, "--plot")
    check_export_paths(args.export_h5, args.export_colmap, h5_name="--export-h5", colmap_name="--export-colmap")


def _filters(values) -> list[str]:
    if values is None:
        return ["dtm"]
    names = [t.strip() for v in values for t in v.split(",") if t.strip()]
    return [n for n in names if n.lower() != "none"]


def _check_numbers(args) -> None:
    if args.max_keypoints is not None and args.max_keypoints < 0:
        raise ValueError(f"--max-keypoints must be >= 0, got {args.max_keypoints}")
    if args.model_threshold is not None and not (args.model_threshold > 0 and args.model_threshold < float("inf")):
        raise ValueError(f"--model-threshold must be a positive number of pixels, got {args.model_threshold}")


def _settings(args) -> dict:
    """The library settings of the flags, each resolved here so that its error names the flag (the library's
    errors name its parameter; :func:`_check_numbers` ran first). Raises ``ValueError`` with the message to
    print."""
    from ..match import as_filter_list, resolve_blob, resolve_features

    settings = dict(filters=_filters(args.filters), model=args.model, model_kind=args.model_kind,
                    model_threshold=args.model_threshold, max_keypoints=args.max_keypoints, rng=args.seed,
                    cache_dir=False if args.no_cache else None)
    for flag, resolve, key in (("--features", resolve_features, "features"), ("--blob", resolve_blob, "blob")):
        try:
            settings[key] = resolve(getattr(args, key))
        except ValueError as exc:
            raise ValueError(f"{flag}: {exc}") from None
    try:
        as_filter_list(settings["filters"])
    except ValueError as exc:
        raise ValueError(f"--filter: {exc}") from None
    if args.export_h5 is not None:
        from .._numerics.extras import require

        try:
            require("h5py", "export", "--export-h5")
        except ImportError as exc:
            raise ValueError(str(exc)) from None
    return settings


def _start_features(args):
    """The two images' features, started before the other settings load (a second of imports on a cold
    start); ``None`` where a flag or an image is wrong, which the checks that follow report by its flag."""
    from ..match import PairFeatures

    if not all(Path(image).is_file() for image in args.images_pair):
        return None
    try:
        return PairFeatures(*args.images_pair, features=args.features, max_keypoints=args.max_keypoints,
                            cache_dir=False if args.no_cache else None)
    except (ValueError, OSError, ImportError):
        return None


def _run_one(args, settings, pending=None) -> dict:
    """Two images: match, save, plot. Returns ``{(name1, name2): npz path}`` for the exports."""
    from ..match import match_images, plot_result, save_plot, save_result

    img1, img2 = (Path(a) for a in args.images_pair)
    if pending is not None:
        rest = {k: v for k, v in settings.items() if k not in ("features", "max_keypoints", "cache_dir")}
        res = pending.match(**rest)
    else:
        res = match_images(img1, img2, **settings)
    out = Path(args.out or "matches.npz")
    save_result(res, out)
    print(f"{len(res.kpts1)} + {len(res.kpts2)} keypoints, {len(res.candidates)} blob candidates, "
          f"{len(res.matches)} matches kept -> {out}")
    if args.plot:
        print(f"picture -> {save_plot(plot_result(res, img1, img2), args.plot)}")
    # Export names: the file names, or the paths as given when the two file names are the same.
    names = (img1.name, img2.name) if img1.name != img2.name else (args.images_pair[0], args.images_pair[1])
    return {names: out}


def _plot_saved_pair(args, plot_dir: Path | None):
    """The ``on_pair`` callback of the folder mode: a picture per pair from its saved ``.npz``."""
    import numpy as np

    from ..match import MatchResult, load_result, plot_result, save_plot

    def on_pair(name1, name2, path, skipped):
        if plot_dir is None:
            return
        pic = plot_dir / (path.stem + ".png")
        if skipped and pic.is_file():
            return
        d = load_result(path)
        keep = np.ones(len(d["matches"]), bool)  # only the kept matches are stored
        res = MatchResult(d["kpts1"], d["kpts2"], d["shapes1"], d["shapes2"], d["matches"], d["scores"],
                          d["matches"], d["scores"], keep, tuple(d["image_size1"]), tuple(d["image_size2"]),
                          settings=d["settings"])
        save_plot(plot_result(res, Path(args.images) / name1, Path(args.images) / name2,
                              title=f"{name1} - {name2}: {len(d['matches'])} matches"), pic)

    return on_pair


def _run_folder(args, settings) -> dict:
    """``--pairs``/``--images``: one ``.npz`` per pair, resumable. Returns the exports' ``{names: path}``."""
    from ..match import match_pairs, read_pairs

    try:
        pairs = read_pairs(args.pairs)
    except (OSError, ValueError) as exc:
        raise ValueError(f"--pairs: {exc}") from None
    if not pairs:
        raise ValueError(f"--pairs: {args.pairs} lists no pair")
    out_dir = Path(args.out or "matches")
    on_pair = _plot_saved_pair(args, Path(args.plot) if args.plot else None)
    summary = match_pairs(pairs, args.images, out_dir, progress=not args.no_progress, on_pair=on_pair, **settings)
    print(f"{len(pairs)} pairs: {summary['done']} matched, {summary['skipped']} already done -> {out_dir}")
    return summary["files"]


def run(args) -> int:
    folder = args.pairs is not None
    if folder:
        if args.images_pair:
            return error("match", "give either two images or --pairs/--images, not both")
        if args.images is None:
            return error("match", "--pairs needs --images DIR (the folder the names are relative to)")
    elif len(args.images_pair) != 2:
        return error("match", f"give two images (or --pairs FILE --images DIR), got {len(args.images_pair)}")
    try:
        _check_inputs_and_outputs(args, folder)
        _check_numbers(args)
        pending = None if folder else _start_features(args)
        settings = _settings(args)
    except ValueError as exc:
        return error("match", str(exc))
    from ..match import kernels_ready

    if not kernels_ready():
        print("ctxmatch match: compiling the kernels of matching, once per machine (about half a minute; "
              "'ctxmatch warmup' does it ahead)", file=sys.stderr, flush=True)
    try:
        results = _run_folder(args, settings) if folder else _run_one(args, settings, pending)
    except (FileNotFoundError, ValueError, ImportError) as exc:  # ImportError: a missing optional dependency
        return error("match", str(exc))

    if args.export_h5 is not None or args.export_colmap is not None:
        from ..io.export import export_results

        try:
            report = export_results(results, h5_dir=args.export_h5, colmap_db=args.export_colmap)
        except (ValueError, OSError) as exc:
            return error("match", f"export failed: {exc}")
        for line in report:
            print(line)
    return 0
