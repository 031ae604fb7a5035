"""Speed and accuracy of ``blob.overlap.ellipse_overlap_error`` (FGINN by overlap).

Prints, for P pairs of random ellipses (many overlapping), the time of the library function next to the
400-point quadrature it replaced (reproduced below, as it was) and their ratio, and each one's largest
absolute error against 2048-gon shapely polygons, with the documented bound 0.01.
Run: ``.venv/bin/python benchmarks/bench_overlap.py [--pairs P]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from _common import best_of


def _disk_samples(n: int = 400) -> np.ndarray:
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n)
    theta = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)


_S = _disk_samples()


def _inside(ca, Aa, cb, Ab):
    pts = ca[:, None, :] + np.einsum("pij,sj->psi", Aa, _S)
    u = np.einsum("pij,psj->psi", np.linalg.inv(Ab), pts - cb[:, None, :])
    return np.mean(np.sum(u * u, axis=2) <= 1.0, axis=1)


def quadrature_overlap_error(c1, A1, c2, A2, chunk: int = 4096):
    """The previous implementation: 400-point quadrature of each ellipse, the two estimates averaged."""
    out = np.ones(len(c1))
    r1 = np.linalg.norm(A1, ord=2, axis=(1, 2))
    r2 = np.linalg.norm(A2, ord=2, axis=(1, 2))
    near = np.flatnonzero(np.sum((c1 - c2) ** 2, axis=1) < (r1 + r2) ** 2)
    for s in range(0, len(near), chunk):
        i = near[s: s + chunk]
        a1, a2 = np.abs(np.linalg.det(A1[i])), np.abs(np.linalg.det(A2[i]))
        inter = 0.5 * (_inside(c1[i], A1[i], c2[i], A2[i]) * a1 + _inside(c2[i], A2[i], c1[i], A1[i]) * a2)
        out[i] = 1.0 - inter / (a1 + a2 - inter)
    return np.clip(out, 0.0, 1.0)


def reference(c1, A1, c2, A2, k: int = 2048):
    import shapely

    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    u = np.stack([np.cos(t), np.sin(t)], 1)
    out = np.empty(len(c1))
    for i in range(len(c1)):
        p, q = shapely.Polygon(c1[i] + u @ A1[i].T), shapely.Polygon(c2[i] + u @ A2[i].T)
        out[i] = 1 - p.intersection(q).area / p.union(q).area
    return out


def main(argv=None) -> None:
    from ctxmatch_lib.blob.overlap import ellipse_overlap_error

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=5000)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(1)
    P = args.pairs
    c1 = rng.uniform(0, 20, (P, 2))
    c2 = c1 + rng.normal(0, 6, (P, 2))
    A1, A2 = rng.normal(0, 4, (P, 2, 2)), rng.normal(0, 4, (P, 2, 2))
    ref = reference(c1, A1, c2, A2)
    t_new, e_new = best_of(lambda: ellipse_overlap_error(c1, A1, c2, A2))
    t_old, e_old = best_of(lambda: quadrature_overlap_error(c1, A1, c2, A2))
    print(f"ellipse_overlap_error on {P} pairs ({np.mean(ref < 1):.0%} overlapping), best of 3")
    for label, t, e in (("library (equal-area 32-gons, shapely)", t_new, e_new),
                        ("previous 400-point quadrature", t_old, e_old)):
        print(f"  {label:<38} {1e3 * t:8.1f} ms   max |error| {np.abs(e - ref).max():.2e}")
    print(f"  speed-up: {t_old / t_new:.1f}x   documented bound: 1.0e-02")


if __name__ == "__main__":
    main()
