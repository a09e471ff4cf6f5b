"""Contact geometry of cylindrical bodies (paper 000 §IV: robots are cylinders of radius r, height h).

Two bodies whose reference points differ by d touch when |d_xy| < 2r and |d_z| < h: the Minkowski
difference of two such cylinders is a cylinder of radius R = 2r and half-height H = h. Everything
here works on that difference, vectorised over many pairs with numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from common.domain.mapfile import MapSpec

EPS = 1e-9


def bodies_touch(d: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Whether bodies with reference-point differences d (..., 3) intersect."""
    d = np.asarray(d, dtype=float)
    return (np.hypot(d[..., 0], d[..., 1]) < 2 * radius - EPS) & (np.abs(d[..., 2]) < height - EPS)


def contact_intervals(p0: np.ndarray, p1: np.ndarray, big_r, big_h) -> tuple[np.ndarray, np.ndarray]:
    """For relative positions moving linearly d(s) = p0 + s (p1 - p0), s in [0, 1], the open range of s
    where |d_xy| < big_r and |d_z| < big_h (scalars or one value per row). Returns (lo, hi) arrays;
    lo >= hi means no contact.

    Both conditions hold on an interval of s (a quadratic and a linear inequality), so their
    intersection is one interval: exact, no sampling.
    """
    p0 = np.atleast_2d(np.asarray(p0, dtype=float))
    p1 = np.atleast_2d(np.asarray(p1, dtype=float))
    d = p1 - p0
    lo = np.zeros(len(p0))
    hi = np.ones(len(p0))
    # |z0 + s dz| < H
    z0, dz = p0[:, 2], d[:, 2]
    moving = np.abs(dz) > EPS
    with np.errstate(divide="ignore", invalid="ignore"):
        za = np.where(moving, (-big_h - z0) / dz, -np.inf)
        zb = np.where(moving, (big_h - z0) / dz, np.inf)
    zlo = np.minimum(za, zb)
    zhi = np.maximum(za, zb)
    still_out = ~moving & (np.abs(z0) >= big_h - EPS)
    lo = np.maximum(lo, zlo)
    hi = np.minimum(hi, zhi)
    hi = np.where(still_out, -1.0, hi)
    # a s^2 + b s + c < 0 with a = |d_xy|^2, b = 2 p0_xy . d_xy, c = |p0_xy|^2 - R^2
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (p0[:, 0] * d[:, 0] + p0[:, 1] * d[:, 1])
    c = p0[:, 0] ** 2 + p0[:, 1] ** 2 - (big_r - EPS) ** 2
    disc = b * b - 4 * a * c
    flat = a <= EPS * EPS
    sq = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(flat, -np.inf, (-b - sq) / (2 * a))
        r2 = np.where(flat, np.inf, (-b + sq) / (2 * a))
    xy_never = np.where(flat, c >= 0, disc <= 0)
    lo = np.maximum(lo, r1)
    hi = np.minimum(hi, r2)
    hi = np.where(xy_never, -1.0, hi)
    return lo, hi


def segment_hits_body(a: np.ndarray, b: np.ndarray, q: np.ndarray, radius: float, height: float):
    """Range of s in [0, 1] where a body moving a->b touches a body resting at q. (lo, hi) per row."""
    q = np.asarray(q, dtype=float)
    return contact_intervals(np.asarray(a) - q, np.asarray(b) - q, 2 * radius, height)


def segment_pair_windows(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, radius: float, height: float, samples: int = 12
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For pairs of segments a->b (param s) and c->d (param u): the range of s at which a body on the
    first can touch a body anywhere on the second, and the range of u likewise.

    Conservative (a superset): u is sampled, and the contact cylinder is grown by the largest distance
    between a point of c->d and its nearest sample, so no contact is missed. Returns (slo, shi, ulo, uhi);
    lo >= hi means the segments never bring the bodies into contact.
    """
    a, b, c, d = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (a, b, c, d))
    n = len(a)
    fractions = (np.arange(samples) + 0.5) / samples

    def windows(p, q, r, w):
        grow = np.linalg.norm(w - r, axis=1) / (2 * samples)
        slo = np.full(n, np.inf)
        shi = np.full(n, -np.inf)
        for f in fractions:
            pt = r + f * (w - r)
            lo_k, hi_k = contact_intervals(p - pt, q - pt, 2 * radius + grow, height + grow)
            hit = lo_k < hi_k
            slo = np.where(hit, np.minimum(slo, lo_k), slo)
            shi = np.where(hit, np.maximum(shi, hi_k), shi)
        return slo, shi

    slo, shi = windows(a, b, c, d)
    ulo, uhi = windows(c, d, a, b)
    none = (slo >= shi) | (ulo >= uhi)
    return (np.where(none, 1.0, slo), np.where(none, 0.0, shi), np.where(none, 1.0, ulo), np.where(none, 0.0, uhi))


def point_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule for (N, 2) points in a polygon (M, 2)."""
    points = np.atleast_2d(points)
    x, y = points[:, 0:1], points[:, 1:2]
    px, py = polygon[:, 0], polygon[:, 1]
    qx, qy = np.roll(px, -1), np.roll(py, -1)
    crosses = (py > y) != (qy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = px + (y - py) * (qx - px) / (qy - py)
    return (np.sum(crosses & (x < xint), axis=1) % 2) == 1


def distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance from (N, 2) points to the boundary of a polygon (M, 2); 0 inside."""
    points = np.atleast_2d(points)
    p = polygon
    q = np.roll(polygon, -1, axis=0)
    seg = q - p
    rel = points[:, None, :] - p[None, :, :]
    t = np.clip(np.sum(rel * seg, axis=2) / np.maximum(np.sum(seg * seg, axis=1), EPS), 0.0, 1.0)
    closest = p[None, :, :] + t[:, :, None] * seg[None, :, :]
    dist = np.min(np.linalg.norm(points[:, None, :] - closest, axis=2), axis=1)
    return np.where(point_in_polygon(points, polygon), 0.0, dist)


def touches_keep_out(spec: MapSpec, pts: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Whether a body (a cylinder of `radius` x `height`) centred at each point (N, 3) would touch
    one of the map's no-fly zones or obstacles."""
    pts = np.atleast_2d(pts)
    out = np.zeros(len(pts), dtype=bool)
    for zone in spec.no_fly:
        poly = np.asarray(zone.polygon, dtype=float)
        in_z = (pts[:, 2] + height / 2 > zone.z[0]) & (pts[:, 2] - height / 2 < zone.z[1])
        near = distance_to_polygon(pts[:, :2], poly) < radius
        out |= in_z & (near | point_in_polygon(pts[:, :2], poly))
    for box in spec.obstacles:
        lo = np.asarray(box.min) - (radius, radius, height / 2)
        hi = np.asarray(box.max) + (radius, radius, height / 2)
        out |= np.all((pts > lo) & (pts < hi), axis=1)
    return out
