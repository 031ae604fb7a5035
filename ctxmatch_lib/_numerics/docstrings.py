"""Parameter texts shared by many docstrings (as scipy's ``_lib/doccer``): :data:`SHARED`,
:func:`compose_doc` and the decorator :func:`shared_doc`."""

from __future__ import annotations

import re
from collections.abc import Mapping

__all__ = ["SHARED", "compose_doc", "shared_doc"]

#: The conventions of the whole library: keypoints, matches, scores, image sizes.
SHARED: dict[str, str] = {
    "kpts": """\
kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
    Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.""",
    "kpts_one": """\
kpts : ndarray of shape (N, 2)
    Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.""",
    "pts": """\
pts1, pts2 : ndarray of shape (K, 2)
    Corresponding points as (x, y) pixels, origin at the centre of the top-left pixel.""",
    "matches": """\
matches : ndarray of shape (K, 2)
    Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.""",
    "scores": """\
scores : ndarray of shape (K,)
    Score of each match, lower is better.""",
    "image_size": """\
image_size1, image_size2 : (int, int)
    Image sizes as (width, height) in pixels.""",
    "shapes": """\
shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
    Affine shape ``A`` of each keypoint (its patch is ``{{kpt + A u : |u| <= 1}}``).""",
}

_PLACEHOLDER = re.compile(r"^([ \t]*)%\((\w+)\)s[ \t]*$", re.M)


def compose_doc(doc: str | None, docs: Mapping[str, str] = SHARED, **fields) -> str | None:
    """``doc`` with every line holding only ``%(name)s`` replaced by ``docs[name]``, indented alike and
    formatted with ``fields``; entries may hold placeholders, other ``%`` signs are left alone.

    Examples
    --------
    >>> print(compose_doc('''Parameters
    ...     ----------
    ...     %(kpts_one)s'''))
    Parameters
        ----------
        kpts : ndarray of shape (N, 2)
            Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    """
    if doc is None:
        return None

    def entry(m: re.Match) -> str:
        indent, name = m.groups()
        if name not in docs:
            raise KeyError(f"no shared documentation named {name!r}")
        text = docs[name].format(**fields) if "{" in docs[name] else docs[name]
        text = compose_doc(text, docs, **fields)  # an entry may be made of entries
        return "\n".join(indent + line if line else line for line in text.splitlines())

    return _PLACEHOLDER.sub(entry, doc)


def shared_doc(func=None, /, docs: Mapping[str, str] = SHARED, **fields):
    """Decorator: compose the ``%(name)s`` lines of the function's docstring from ``docs``."""

    def apply(f):
        f.__doc__ = compose_doc(f.__doc__, docs, **fields)
        return f

    return apply(func) if func is not None else apply
