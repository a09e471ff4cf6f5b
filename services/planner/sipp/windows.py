"""Exact blocked departure windows for pairs of edges (paper 000 §IV bodies, §V-D safe intervals).

A body enters edge e at t1 and traverses it linearly in D_e; another enters edge f at tau and
traverses it in D_f. At the instant when the first is at parameter s of e and the second at u of
f, tau = t1 + s D_e - u D_f. The bodies touch at (s, u) when d = p + s a - u b (p = e0 - f0,
a = e1 - e0, b = f1 - f0) has |d_xy| < R = 2r and |d_z| < H = h. That set C of (s, u) in the unit
square is convex (an affine preimage of a convex cylinder), so the blocked departures form one open
interval tau - t1 in (min L, max L) of the linear L = s D_e - u D_f over C: the bounding box of C
(the Conflicts windows) gives a superset, this gives the interval itself.

The extremes of a linear function over C = square ∩ z-strip ∩ xy-ellipse lie at the intersections of
two of the six lines bounding square and strip, at the intersections of such a line with the
ellipse, or at the ellipse's own extreme points in the direction of L: all candidates are
enumerated in closed form, the feasible ones kept (with a small outward tolerance, so the windows
err on the blocking side).
"""

from __future__ import annotations

import numpy as np

TOL = 1e-9  # outward tolerance on parameters and lengths
CHUNK = 20000  # pairs per vectorised batch (bounds memory)


def edge_pair_windows(
    pos: np.ndarray, edges: np.ndarray, duration: np.ndarray, e: np.ndarray, f: np.ndarray, radius: float, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """For each pair (e[k], f[k]): the open window (lo, hi) of tau - t1 in which a body entering f at
    tau touches one that entered e at t1 (both moving linearly); lo >= hi when they never touch.
    Swapping the roles negates the window, so a pair listed both ways is computed once."""
    e, f = np.asarray(e, dtype=np.int64), np.asarray(f, dtype=np.int64)
    m = len(edges)
    key = e * m + f
    uniq, inverse = np.unique(np.where(e <= f, key, f * m + e), return_inverse=True)
    ue, uf = uniq // m, uniq % m
    ulo = np.empty(len(uniq))
    uhi = np.empty(len(uniq))
    for k in range(0, len(uniq), CHUNK):
        sl = slice(k, k + CHUNK)
        ee, ff = ue[sl], uf[sl]
        e0, e1 = pos[edges[ee, 0]], pos[edges[ee, 1]]
        f0, f1 = pos[edges[ff, 0]], pos[edges[ff, 1]]
        ulo[sl], uhi[sl] = _windows(e0 - f0, e1 - e0, f1 - f0, duration[ee], duration[ff], 2 * radius, height)
    lo, hi = ulo[inverse], uhi[inverse]
    swapped = e > f
    return np.where(swapped, -hi, lo), np.where(swapped, -lo, hi)


def _windows(p, a, b, de, df, big_r, big_h):
    n = len(p)
    # the six lines n . x = k bounding the square (x = (s, u)) and the z-strip |p_z + s a_z - u b_z| <= H
    normals = np.zeros((n, 6, 2))
    offsets = np.zeros((n, 6))
    normals[:, 0:2, 0] = 1.0
    offsets[:, 1] = 1.0
    normals[:, 2:4, 1] = 1.0
    offsets[:, 3] = 1.0
    for i, sign in ((4, 1.0), (5, -1.0)):
        normals[:, i, 0] = a[:, 2]
        normals[:, i, 1] = -b[:, 2]
        offsets[:, i] = sign * big_h - p[:, 2]
    cands = [_line_line(normals, offsets, i, j) for i in range(6) for j in range(i + 1, 6)]
    mx = np.stack([a[:, :2], -b[:, :2]], axis=2)  # d_xy = p_xy + mx @ x
    cands += [pt for i in range(6) for pt in _line_ellipse(normals[:, i], offsets[:, i], p[:, :2], mx, big_r)]
    cands += _ellipse_extremes(p[:, :2], mx, de, df, big_r)
    x = np.stack([c[0] for c in cands], axis=1)  # (n, K, 2)
    valid = np.stack([c[1] for c in cands], axis=1)
    s, u = x[..., 0], x[..., 1]
    d = p[:, None, :] + s[..., None] * a[:, None, :] - u[..., None] * b[:, None, :]
    inside = (
        valid
        & (s >= -TOL) & (s <= 1 + TOL) & (u >= -TOL) & (u <= 1 + TOL)
        & (np.abs(d[..., 2]) <= big_h + TOL)
        & (np.hypot(d[..., 0], d[..., 1]) <= big_r + TOL)
    )
    lin = s * de[:, None] - u * df[:, None]
    lo = np.where(inside, lin, np.inf).min(axis=1)
    hi = np.where(inside, lin, -np.inf).max(axis=1)
    none = ~inside.any(axis=1)
    pad = TOL * (de + df)
    return np.where(none, 1.0, lo - pad), np.where(none, 0.0, hi + pad)


def _line_line(normals, offsets, i, j):
    n1, n2 = normals[:, i], normals[:, j]
    k1, k2 = offsets[:, i], offsets[:, j]
    det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
    ok = np.abs(det) > 1e-12
    safe = np.where(ok, det, 1.0)
    x = np.stack([(k1 * n2[:, 1] - k2 * n1[:, 1]) / safe, (n1[:, 0] * k2 - n2[:, 0] * k1) / safe], axis=1)
    return x, ok


def _line_ellipse(normal, offset, p, mx, big_r):
    """The (up to two) points of the line normal . x = offset where |p + mx x| = R."""
    nn = np.einsum("ij,ij->i", normal, normal)
    ok = nn > 1e-24
    x0 = normal * (offset / np.where(ok, nn, 1.0))[:, None]
    w = np.stack([-normal[:, 1], normal[:, 0]], axis=1)
    y0 = p + np.einsum("ijk,ik->ij", mx, x0)
    mw = np.einsum("ijk,ik->ij", mx, w)
    qa = np.einsum("ij,ij->i", mw, mw)
    qb = 2 * np.einsum("ij,ij->i", y0, mw)
    qc = np.einsum("ij,ij->i", y0, y0) - big_r**2
    disc = qb * qb - 4 * qa * qc
    ok &= (qa > 1e-24) & (disc >= 0)
    root = np.sqrt(np.maximum(disc, 0.0))
    den = np.where(ok, 2 * qa, 1.0)
    return [(x0 + ((-qb + sgn * root) / den)[:, None] * w, ok) for sgn in (1.0, -1.0)]


def _ellipse_extremes(p, mx, de, df, big_r):
    """Where L = s D_e - u D_f is extreme on the ellipse |p + mx x| = R (mx invertible): with
    y = p + mx x, L = (mx^-T c) . y + const, extreme at y = +-R g / |g| for g = mx^-T c."""
    det = mx[:, 0, 0] * mx[:, 1, 1] - mx[:, 0, 1] * mx[:, 1, 0]
    scale = np.einsum("ijk,ijk->i", mx, mx)
    ok = np.abs(det) > 1e-9 * np.maximum(scale, 1e-300)
    safe = np.where(ok, det, 1.0)
    inv = np.stack(
        [np.stack([mx[:, 1, 1], -mx[:, 0, 1]], axis=1), np.stack([-mx[:, 1, 0], mx[:, 0, 0]], axis=1)], axis=1
    ) / safe[:, None, None]
    c = np.stack([de, -df], axis=1)
    g = np.einsum("ikj,ik->ij", inv, c)  # inv^T c
    gn = np.linalg.norm(g, axis=1)
    ok &= gn > 0
    unit = g / np.where(ok, gn, 1.0)[:, None]
    return [(np.einsum("ijk,ik->ij", inv, sgn * big_r * unit - p), ok) for sgn in (1.0, -1.0)]
