"""Blob-matching configurations: the parameters of Sec. 3, the named presets and the grid of Sec. 5.2."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from itertools import product

from .._numerics.validation import Presets

__all__ = ["BlobConfig", "BLOB_PRESETS", "blob_grid", "RATIOS", "COMBINES", "PREFILTERS", "T_O_KINDS"]

RATIOS = ("D>=", "D+>=", "D+")
COMBINES = ("a", "b", "min", "max", "harmonic")
PREFILTERS = ("cap", "cup")
T_O_KINDS = ("px", "overlap")
_PREFILTER_ALIASES = {"cap": "cap", "∩": "cap", "cup": "cup", "∪": "cup"}


def _check_f(f) -> int | str:
    if isinstance(f, str):
        if f.lower() in ("omega", "ω"):
            return "omega"
        raise ValueError(f"f must be a positive int or 'omega', got {f!r}")
    if isinstance(f, bool) or not float(f).is_integer() or f < 1:
        raise ValueError(f"f must be a positive int or 'omega', got {f!r}")
    return int(f)


def _check_t_o(t_o, t_o_kind: str) -> float | None:
    if t_o_kind not in T_O_KINDS:
        raise ValueError(f"t_o_kind must be one of {T_O_KINDS}, got {t_o_kind!r}")
    if t_o is None or (isinstance(t_o, (int, float)) and math.isinf(t_o) and t_o > 0):
        return None
    t_o = float(t_o)
    if math.isnan(t_o) or t_o <= 0:
        raise ValueError(f"t_o must be positive, None or math.inf, got {t_o!r}")
    if t_o_kind == "overlap" and not t_o < 1:
        raise ValueError(f"t_o with t_o_kind='overlap' is an overlap error in (0, 1), got {t_o!r}")
    return t_o


@dataclass(frozen=True)
class BlobConfig:
    """One blob-matching setup (Sec. 3, steps 1-4): the keywords of :func:`~ctxmatch_lib.blob.blob_matching`,
    validated and normalised (``"∩"``/``"∪"`` aliases, ``t_o = math.inf`` as ``None``)."""

    f: int | str = 10
    prefilter: str = "cup"
    f_prime: int = 5
    ratio: str = "D+"
    t_o: float | None = 10.0
    t_o_kind: str = "px"
    combine: str = "harmonic"

    def __post_init__(self) -> None:
        object.__setattr__(self, "f", _check_f(self.f))
        if self.prefilter not in _PREFILTER_ALIASES:
            raise ValueError(f"prefilter must be 'cap' or 'cup', got {self.prefilter!r}")
        object.__setattr__(self, "prefilter", _PREFILTER_ALIASES[self.prefilter])
        fp = self.f_prime
        if isinstance(fp, bool) or not float(fp).is_integer() or fp < 1:
            raise ValueError(f"f_prime must be a positive int, got {fp!r}")
        object.__setattr__(self, "f_prime", int(fp))
        if self.ratio not in RATIOS:
            raise ValueError(f"ratio must be one of {RATIOS}, got {self.ratio!r}")
        if self.combine not in COMBINES:
            raise ValueError(f"combine must be one of {COMBINES}, got {self.combine!r}")
        object.__setattr__(self, "t_o", _check_t_o(self.t_o, self.t_o_kind))

    def kwargs(self) -> dict:
        """The keyword arguments of :func:`blob_matching` for this setup."""
        return asdict(self)

    @property
    def candidate_key(self) -> tuple:
        """What the candidate set G depends on: (f, prefilter, f'); the other fields only rank it."""
        return (self.f, "cup" if self.f == "omega" else self.prefilter, self.f_prime)

    @property
    def f_label(self) -> str:
        """``"10∪"``, ``"3∩"`` or ``"Ω"`` as in the paper's figures."""
        if self.f == "omega":
            return "Ω"
        return f"{self.f}{'∪' if self.prefilter == 'cup' else '∩'}"

    @property
    def t_o_label(self) -> str:
        """``"∞"``, ``"10px"`` or ``"75%"`` as in the paper's figures."""
        if self.t_o is None:
            return "∞"
        if self.t_o_kind == "px":
            return f"{self.t_o:g}px"
        return f"{100 * self.t_o:g}%"

    @property
    def label(self) -> str:
        """A short human-readable label, e.g. ``"f=10∪ f'=5 t_o=10px D+ W=harmonic"``."""
        return f"f={self.f_label} f'={self.f_prime} t_o={self.t_o_label} {self.ratio} W={self.combine}"


BLOB_PRESETS: dict[str, BlobConfig] = Presets("blob preset", {
    # Best setup of Sec. 5.2: f = 10∪, f' = 5, D+ with t_o = 10 px, harmonic W.
    "paper-best": BlobConfig(f=10, prefilter="cup", f_prime=5, ratio="D+", t_o=10.0, t_o_kind="px",
                             combine="harmonic"),
    # The same with t_o = 75 % overlap error, which the paper ranks equal.
    "paper-best-overlap": BlobConfig(f=10, prefilter="cup", f_prime=5, ratio="D+", t_o=0.75,
                                     t_o_kind="overlap", combine="harmonic"),
    # One-to-one greedy NN ranked by plain NNR: the paper's baseline configuration (Sec. 5.3).
    "baseline": BlobConfig(f="omega", prefilter="cup", f_prime=1, ratio="D>=", t_o=None,
                           combine="a"),
})

# The values of Sec. 5.2, in the order of the heat map of Fig. 5.
GRID_F = ((1, "cup"), (1, "cap"), (3, "cup"), (3, "cap"), (5, "cup"), (5, "cap"), (10, "cup"), (10, "cap"),
          ("omega", "cup"))
GRID_F_PRIME = (1, 3, 5)
GRID_T_O = ((None, "px"), (0.50, "overlap"), (0.75, "overlap"), (0.99, "overlap"), (5.0, "px"), (10.0, "px"))


def blob_grid() -> list[BlobConfig]:
    """The 2430 setups of Sec. 5.2 (``GRID_F`` × ``GRID_F_PRIME`` × ``GRID_T_O`` × D × W), f × f' outermost as
    in Fig. 5.

    Examples
    --------
    >>> grid = blob_grid()
    >>> len(grid), len({c.candidate_key for c in grid})
    (2430, 27)
    """
    return [
        BlobConfig(f=f, prefilter=pre, f_prime=fp, ratio=ratio, t_o=t_o, t_o_kind=kind, combine=w)
        for (f, pre), fp, (t_o, kind), ratio, w in product(GRID_F, GRID_F_PRIME, GRID_T_O, RATIOS, COMBINES)
    ]
