"""Colour-blind-safe colours of the figures (Okabe & Ito 2008, "Color Universal Design") and their check:
:func:`simulate_cvd` (Machado, Oliveira & Fernandes 2009, IEEE TVCG 15(6), severity 1.0, linear sRGB) and
:func:`delta_e` (CIE 1976 ΔE in CIELAB, D65 white)."""

from __future__ import annotations

import numpy as np

__all__ = ["OKABE_ITO", "simulate_cvd", "to_lab", "delta_e"]

#: The eight colours of the Okabe–Ito palette.
OKABE_ITO = {"black": "#000000", "orange": "#E69F00", "sky_blue": "#56B4E9", "bluish_green": "#009E73",
             "yellow": "#F0E442", "blue": "#0072B2", "vermillion": "#D55E00", "reddish_purple": "#CC79A7"}

# Machado et al. 2009, Table 1, severity 1.0 (linear RGB -> simulated linear RGB).
_CVD_MATRICES = {
    "protanopia": np.array([[0.152286, 1.052583, -0.204868],
                            [0.114503, 0.786281, 0.099216],
                            [-0.003882, -0.048116, 1.051998]]),
    "deuteranopia": np.array([[0.367322, 0.860646, -0.227968],
                              [0.280085, 0.672501, 0.047413],
                              [-0.011820, 0.042940, 0.968881]]),
    "tritanopia": np.array([[1.255528, -0.076749, -0.178779],
                            [-0.078411, 0.930809, 0.147602],
                            [0.004733, 0.691367, 0.303900]]),
}


def _rgb(colors) -> np.ndarray:
    """Any matplotlib colour, or a list of them, as an (N, 3) array of sRGB in [0, 1]."""
    from matplotlib.colors import to_rgb

    if isinstance(colors, str) or (np.ndim(colors) == 1 and len(colors) in (3, 4)
                                   and not isinstance(colors[0], str)):
        colors = [colors]
    return np.array([to_rgb(c) for c in colors], np.float64).reshape(-1, 3)


def _to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _from_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def simulate_cvd(colors, kind: str = "deuteranopia") -> np.ndarray:
    """Simulated sRGB ``(N, 3)`` in [0, 1] of ``colors`` (anything ``to_rgb`` accepts) seen with the full
    dichromacy ``kind`` ("deuteranopia", "protanopia", "tritanopia").

    Examples
    --------
    >>> simulate_cvd("#ffffff").round(3).tolist()  # white stays white
    [[1.0, 1.0, 1.0]]
    """
    if kind not in _CVD_MATRICES:
        raise ValueError(f"kind must be one of {sorted(_CVD_MATRICES)}, got {kind!r}")
    lin = _to_linear(_rgb(colors))
    return _from_linear(lin @ _CVD_MATRICES[kind].T)


def to_lab(colors) -> np.ndarray:
    """CIELAB ``(N, 3)`` (L*, a*, b*) of sRGB colours, D65 reference white."""
    lin = _to_linear(_rgb(colors))
    xyz = lin @ np.array([[0.4124564, 0.3575761, 0.1804375],
                          [0.2126729, 0.7151522, 0.0721750],
                          [0.0193339, 0.1191920, 0.9503041]]).T
    t = xyz / np.array([0.95047, 1.0, 1.08883])
    d = 6 / 29
    f = np.where(t > d ** 3, np.cbrt(t), t / (3 * d * d) + 4 / 29)
    return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], axis=1)


def delta_e(color1, color2, cvd: str | None = None) -> float:
    """CIE 1976 ΔE*ab between two colours, optionally as seen with the dichromacy ``cvd``.

    Examples
    --------
    >>> round(delta_e("#22c02c", "#e8211d", cvd="deuteranopia"), 1)  # the paper's green / red
    12.2
    """
    a, b = _rgb(color1), _rgb(color2)
    if cvd is not None:
        a, b = simulate_cvd(a, cvd), simulate_cvd(b, cvd)
    return float(np.linalg.norm(to_lab(a) - to_lab(b), axis=1)[0])
