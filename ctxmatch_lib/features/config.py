"""Feature settings: :class:`FeatureConfig` and :data:`FEATURE_PRESETS`, the paper's eight detector +
descriptor blocks of Fig. 5 (:func:`paper_feature_blocks`) and the upright and plain SIFT variants."""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass

import numpy as np

from .._numerics.validation import Presets

__all__ = ["FeatureConfig", "FEATURE_PRESETS", "FEATURE_DESCRIPTIONS", "PAPER_FEATURE_BLOCKS", "paper_feature_blocks",
           "KEYPOINT_BUDGETS", "keypoint_budget"]


# Part of FeatureConfig.key(): bump it when the extracted features change, to recompute every cache keyed on it.
_CACHE_FORMAT = 2

_DETECTORS = ("sift", "harrisz")
_DESCRIPTORS = ("rootsift", "sift", "rootsgloh2", "hardnet2", "sosnet")
_DEEP = ("hardnet2", "sosnet")
_ORIENTATIONS = ("auto", "sift", "dominant", "orinet", "none")
_NETS = ("auto", "hardnet", "sosnet", "tfeat", "hardtfeat")

# Left out of the key digest at their defaults, so the keys of the SIFT configurations stay stable.
_NEW_FIELDS = {"orientation": "auto", "weights": None, "net": "auto", "orinet_weights": None, "support": 2.0}


@dataclass(frozen=True)
class FeatureConfig:
    """Settings of the keypoint extractor and descriptor.

    Parameters
    ----------
    detector : {"sift", "harrisz"}
        OpenCV's SIFT (DoG) or :func:`.harrisz.harrisz`.
    descriptor : {"rootsift", "sift", "rootsgloh2", "hardnet2", "sosnet"}
        RootSIFT (Arandjelović & Zisserman 2012), L2-normalised SIFT, RootsGLOH2 (:mod:`.sgloh`) or :mod:`.deep`.
    upright : bool
        Angle 0 for every keypoint; keypoints that differ only by orientation are merged.
    max_keypoints : int
        Cap (0: none), strongest first for SIFT, finest scale then strongest for HarrisZ.
    n_octave_layers, contrast_threshold, edge_threshold, sigma, precise_upscale
        OpenCV ``SIFT_create`` parameters (precise upscaling avoids the quarter-pixel bias).
    patch_radius : float
        Patch radius in units of the keypoint scale (SIFT's 3σ blob); HarrisZ's major semi-axis.
    orientation : {"auto", "sift", "dominant", "orinet", "none"}
        ``"auto"``: none for RootsGLOH2 and upright, SIFT's for SIFT + (Root)SIFT, dominant gradient for
        HarrisZ + (Root)SIFT, OriNet for the deep descriptors.
    weights, orinet_weights, net : str, optional
        Deep descriptor and OriNet weights (:func:`.deep.resolve_weights`; ``None``: kornia's) and the
        architecture of ``weights``.
    support : float
        Patch descriptors sample ``support × A``.
    """

    detector: str = "sift"
    descriptor: str = "rootsift"
    upright: bool = False
    max_keypoints: int = 8000
    n_octave_layers: int = 3
    contrast_threshold: float = 0.04
    edge_threshold: float = 10.0
    sigma: float = 1.6
    precise_upscale: bool = True
    patch_radius: float = 3.0
    orientation: str = "auto"
    weights: str | None = None
    net: str = "auto"
    orinet_weights: str | None = None
    support: float = 2.0

    def __post_init__(self):
        for name, allowed in (("detector", _DETECTORS), ("descriptor", _DESCRIPTORS),
                              ("orientation", _ORIENTATIONS), ("net", _NETS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.orientation == "sift" and self.detector != "sift":
            raise ValueError("orientation='sift' needs detector='sift'")
        if self.descriptor == "rootsgloh2" and self.orientation not in ("auto", "none"):
            raise ValueError("RootsGLOH2 works on non-oriented patches: orientation must be 'auto' or 'none', "
                             f"got {self.orientation!r}")
        if self.descriptor not in _DEEP and (self.weights is not None or self.net != "auto"):
            raise ValueError(f"weights and net apply to the deep descriptors {_DEEP}, not {self.descriptor!r}")
        if not np.isfinite(self.support) or self.support <= 0:
            raise ValueError(f"support must be a positive number, got {self.support!r}")
        if int(self.max_keypoints) != self.max_keypoints or self.max_keypoints < 0:
            raise ValueError(f"max_keypoints must be a non-negative integer, got {self.max_keypoints!r}")
        if int(self.n_octave_layers) != self.n_octave_layers or self.n_octave_layers < 1:
            raise ValueError(f"n_octave_layers must be a positive integer, got {self.n_octave_layers!r}")
        for name in ("contrast_threshold", "edge_threshold", "sigma", "patch_radius"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0 or (name in ("sigma", "patch_radius") and value == 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")

    def key(self) -> str:
        """A stable, file-name-safe string identifying this configuration (used for cache folders).

        Examples
        --------
        >>> FeatureConfig().key()
        'sift-rootsift-k8000-v2-441d0e9b'
        """
        items = sorted((k, v) for k, v in asdict(self).items() if not (k in _NEW_FIELDS and v == _NEW_FIELDS[k]))
        orinet = self.resolved_orientation() == "orinet"
        for field in ("weights", "orinet_weights"):
            if getattr(self, field) is not None or (field == "orinet_weights" and orinet):
                from .deep import weights_digest

                items.append((field + "_sha1", weights_digest(getattr(self, field), field)))
        if self.detector != "sift" or self.descriptor not in ("sift", "rootsift") or orinet:
            # Marks the features computed without BLAS's float32 or batched products (last bits differ).
            items.append(("blas_independent", 1))
        digest = hashlib.sha1(repr(items).encode()).hexdigest()[:8]
        up = "-upright" if self.upright else ""
        return f"{self.detector}-{self.descriptor}{up}-k{self.max_keypoints}-v{_CACHE_FORMAT}-{digest}"

    def resolved_orientation(self) -> str:
        """The orientation ``"auto"`` stands for (see the class docstring)."""
        if self.orientation != "auto":
            return self.orientation
        if self.descriptor == "rootsgloh2" or self.upright:
            return "none"
        if self.descriptor in _DEEP:
            return "orinet"
        return "sift" if self.detector == "sift" else "dominant"


_HARDNET2_STANDIN = dict(weights="HardTFeat.pth", net="hardtfeat", orinet_weights="OriNet.pth")
_SOSNET_STANDIN = dict(weights="tfeat-liberty.params", net="tfeat", orinet_weights="OriNet.pth")


FEATURE_PRESETS = Presets("feature preset", {
    "sift-rootsift": FeatureConfig(),
    "sift-rootsift-upright": FeatureConfig(upright=True),
    "sift": FeatureConfig(descriptor="sift"),
    "sift-rootsgloh2": FeatureConfig(descriptor="rootsgloh2"),
    "harrisz-rootsift": FeatureConfig(detector="harrisz"),
    "harrisz-rootsgloh2": FeatureConfig(detector="harrisz", descriptor="rootsgloh2"),
    "sift-hardnet2": FeatureConfig(descriptor="hardnet2", **_HARDNET2_STANDIN),
    "sift-sosnet": FeatureConfig(descriptor="sosnet", **_SOSNET_STANDIN),
    "harrisz-hardnet2": FeatureConfig(detector="harrisz", descriptor="hardnet2", **_HARDNET2_STANDIN),
    "harrisz-sosnet": FeatureConfig(detector="harrisz", descriptor="sosnet", **_SOSNET_STANDIN),
})


#: One line per preset for tables and figure captions; every stand-in says so and names its weights.
FEATURE_DESCRIPTIONS = {
    "sift-rootsift": "SIFT + RootSIFT (SIFT orientation)",
    "sift-rootsift-upright": "upright SIFT + RootSIFT",
    "sift": "SIFT + SIFT (plain L2)",
    "sift-rootsgloh2": "SIFT + RootsGLOH2 (non-oriented patches, rotation-min distance)",
    "harrisz-rootsift": "HarrisZ + RootSIFT (dominant-gradient orientation: stand-in for the learned orientation)",
    "harrisz-rootsgloh2": "HarrisZ + RootsGLOH2 (non-oriented patches, rotation-min distance)",
    "sift-hardnet2": "SIFT + HardNet2 stand-in (TFeat architecture, weights HardTFeat.pth; "
                     "orientation: OriNet stand-in, OriNet.pth)",
    "sift-sosnet": "SIFT + SOSNet stand-in (TFeat architecture, weights tfeat-liberty.params; "
                   "orientation: OriNet stand-in, OriNet.pth)",
    "harrisz-hardnet2": "HarrisZ + HardNet2 stand-in (TFeat architecture, weights HardTFeat.pth; "
                        "orientation: OriNet stand-in, OriNet.pth)",
    "harrisz-sosnet": "HarrisZ + SOSNet stand-in (TFeat architecture, weights tfeat-liberty.params; "
                      "orientation: OriNet stand-in, OriNet.pth)",
}


#: The eight detector + descriptor blocks of the paper's heat map (Fig. 5), handcrafted ones first.
PAPER_FEATURE_BLOCKS = ("sift-rootsift", "sift-rootsgloh2", "harrisz-rootsift", "harrisz-rootsgloh2",
                        "sift-hardnet2", "sift-sosnet", "harrisz-hardnet2", "harrisz-sosnet")


def paper_feature_blocks(deep: bool | None = None) -> list[str]:
    """The keys of :data:`PAPER_FEATURE_BLOCKS` that can run here (deep ones if ``deep``, or ``None`` and found).

    Examples
    --------
    >>> paper_feature_blocks(deep=False)
    ['sift-rootsift', 'sift-rootsgloh2', 'harrisz-rootsift', 'harrisz-rootsgloh2']
    """
    handcrafted = [k for k in PAPER_FEATURE_BLOCKS if FEATURE_PRESETS[k].descriptor not in _DEEP]
    if deep is False:
        return handcrafted
    if deep is None:
        try:
            for k in PAPER_FEATURE_BLOCKS:
                FEATURE_PRESETS[k].key()  # resolves (and hashes) the weights: FileNotFoundError when missing
        except (FileNotFoundError, ValueError):
            return handcrafted
    return list(PAPER_FEATURE_BLOCKS)


#: Named keypoint caps per image: ``"paper"`` matches the candidate counts of the paper's Table 2
#: (calibrated on counts only, see ``docs/paper-scale.md``); ``"dense"`` is :class:`FeatureConfig`'s default.
KEYPOINT_BUDGETS = {"paper": 1500, "dense": 8000}


def keypoint_budget(value, *, argument: str = "max_keypoints") -> int | None:
    """A keypoint cap from a :data:`KEYPOINT_BUDGETS` name or an integer (0: none; ``None``: the preset's).

    Examples
    --------
    >>> keypoint_budget("paper"), keypoint_budget(4000), keypoint_budget("2000"), keypoint_budget(None)
    (1500, 4000, 2000, None)
    """
    if value is None:
        return None
    if isinstance(value, str):
        name = value.strip()
        if name in KEYPOINT_BUDGETS:
            return KEYPOINT_BUDGETS[name]
        value = int(name) if name.isdigit() else value
    if isinstance(value, (str, bool)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{argument} must be a non-negative integer or a budget name "
                         f"({', '.join(KEYPOINT_BUDGETS)}), got {value!r}")
    return int(value)
