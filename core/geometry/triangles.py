"""Closest points on triangles (Ericson, *Real-Time Collision Detection*, §5.1.5), vectorised."""

from __future__ import annotations

import numpy as np

__all__ = ["closest_point_on_triangles"]


def closest_point_on_triangles(p, a, b, c) -> np.ndarray:
    """Closest points on triangles ``(a, b, c)`` to points ``p``; all ``(N, 3)`` row-wise."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    def ratio(num, den):  # degenerate (zero-area or zero-length) cases: 0, never NaN
        return num / np.where(np.abs(den) < 1e-30, 1.0, den)

    denom = va + vb + vc
    v, w = ratio(vb, denom), ratio(vc, denom)
    q = a + v[:, None] * ab + w[:, None] * ac  # interior by default
    t_ab = ratio(d1, d1 - d3)
    t_ac = ratio(d2, d2 - d6)
    t_bc = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    cases = [  # later cases take precedence, in reverse of Ericson's early returns
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + t_bc[:, None] * (c - b)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d1 <= 0) & (d2 <= 0), a),
    ]
    for cond, pt in cases:
        q = np.where(cond[:, None], pt, q)
    return q
