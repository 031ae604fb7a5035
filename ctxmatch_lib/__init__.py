"""ctxmatch: SIFT Matching by Context Exposed (F. Bellavia, IEEE TPAMI 2022).

Blob matching (Sec. 3), Delaunay Triangulation Matching (Sec. 4, ``ctxmatch_lib.dtm.dtm``) and the evaluation
of Sec. 5; two images to filtered matches in :func:`ctxmatch_lib.match.match_images`, OpenCV / kornia glue in
:mod:`ctxmatch_lib.io.interop`, hloc / COLMAP exports in :mod:`ctxmatch_lib.io.export`. Keypoints everywhere
are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

# The one source of the version (pyproject.toml and ``ctxmatch --version`` read it).
__version__ = "0.1.0"

# The public names, imported on first use (PEP 562): ``import ctxmatch_lib`` and ``ctxmatch match`` start without
# loading the compiled kernels of every step.
_EXPORTS = {
    "blob": ("BLOB_PRESETS", "BlobConfig", "BlobContext", "BlobMatches", "blob_grid", "blob_matching"),
    "datasets": ("Dataset", "Pair", "list_datasets", "load_dataset"),
    "dtm": ("DTMResult", "DTMTrace", "dtm_boundary"),
    "features": ("FeatureConfig", "Features", "extract_features", "load_image"),
    "filters": ("FILTERS", "register_filter"),
    "geometry": ("fit_fundamental", "fit_homography", "one_sac", "ransac"),
    "geometry_metrics": ("epipolar_consistency", "geometry_table", "homography_corner_error", "pose_auc"),
    "groundtruth": ("label_matches",),
    "metrics": ("average_precision", "evaluate_matches", "mean_average_precision"),
    "match": ("MatchResult", "match_images"),
    "pipeline": ("evaluate_dataset", "evaluate_pair", "summary_table"),
}
_SOURCE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = [
    "BLOB_PRESETS",
    "BlobConfig",
    "BlobContext",
    "BlobMatches",
    "DTMResult",
    "DTMTrace",
    "Dataset",
    "FILTERS",
    "FeatureConfig",
    "Features",
    "Pair",
    "blob_grid",
    "blob_matching",
    "dtm",
    "dtm_boundary",
    "extract_features",
    "list_datasets",
    "load_dataset",
    "load_image",
    "register_filter",
    "average_precision",
    "evaluate_dataset",
    "evaluate_matches",
    "evaluate_pair",
    "fit_fundamental",
    "fit_homography",
    "label_matches",
    "MatchResult",
    "match_images",
    "mean_average_precision",
    "one_sac",
    "ransac",
    "homography_corner_error",
    "epipolar_consistency",
    "pose_auc",
    "geometry_table",
    "summary_table",
    "__version__",
]


def __getattr__(name: str):
    import importlib
    import importlib.util

    if name in _SOURCE:
        value = getattr(importlib.import_module(f".{_SOURCE[name]}", __name__), name)
    elif not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f".{name}", __name__)  # a subpackage or module, ``dtm`` included
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


# ----------------------------------------------------------------------------------- moved modules
# Modules the README and the docs named under their former paths keep importing, with a FutureWarning, until the
# next release: ``import ctxmatch_lib.export`` gives ``ctxmatch_lib.io.export`` itself.
_MOVED = {
    "ctxmatch_lib.export": "ctxmatch_lib.io.export",
    "ctxmatch_lib.interop": "ctxmatch_lib.io.interop",
    "ctxmatch_lib.usercache": "ctxmatch_lib.cache",
    "ctxmatch_lib.report_blob": "ctxmatch_lib.report.blob",
    "ctxmatch_lib.report_paper": "ctxmatch_lib.report.paper",
}


def _install_moved_modules() -> None:
    import importlib
    import importlib.abc
    import importlib.util
    import sys
    import warnings

    class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
        """Finds a former module path and loads the module that replaced it."""

        specs: dict = {}

        def find_spec(self, name, path=None, target=None):
            return importlib.util.spec_from_loader(name, self) if name in _MOVED else None

        def create_module(self, spec):
            warnings.warn(f"{spec.name} moved to {_MOVED[spec.name]}; the old path goes in the next release",
                          FutureWarning, stacklevel=3)
            module = importlib.import_module(_MOVED[spec.name])
            self.specs[module.__name__] = module.__spec__
            return module

        def exec_module(self, module):
            # The import machinery set the alias's spec on the module: the module keeps its own.
            module.__spec__ = self.specs[module.__name__]

    if not any(type(f).__name__ == "MovedModules" for f in sys.meta_path):
        sys.meta_path.append(MovedModules())


_install_moved_modules()
