"""The online segmenter's per-sample maths (``estimator.segments.OnlineSegmenter``) for one ray or
one pair of rays at a time, in plain Python floats.

The live loop calls the segmenter once per gaze sample (200 Hz), each time on a handful of
3-vectors: numpy's per-call overhead (``np.cross`` and ``np.median`` on one-row arrays,
``np.quantile`` over the last 600 noise measures converted to an array, a 3x3 solve for the depth
the fixation's lines fix) cost 0.7 ms CPU a sample, more than half the loop's. These give the
same numbers as their numpy counterparts in ``estimator.segments``, ``estimator.segdepth`` and
``estimator.frames`` (to rounding: 1e-12 deg, the depth bounds 1e-9 relative; the medians and
the quantiles bit for bit), NaN where those give NaN (tests/test_segscalar.py checks both).

A vector here is a tuple of 3 floats (``Vec``); frames and units are the callers' (world frame,
mm for origins, unit directions). Origins may be None (unknown) where a docstring says so.
"""

from __future__ import annotations

import math
from bisect import bisect_left, insort
from collections import deque
from collections.abc import Sequence
from typing import Any

from .segdepth import BIAS_DEG, DEPTH_K

Vec = tuple[float, float, float]
Line = tuple[Vec, Vec]
"""A view line: (origin, mm; unit direction), NaN where unknown."""
NAN3: Vec = (math.nan, math.nan, math.nan)


def vec3(x: Any) -> Vec:
    """A (3,) array-like as a ``Vec`` of Python floats."""
    a, b, c = x.tolist() if hasattr(x, "tolist") else x
    return float(a), float(b), float(c)


def _div(x: float, n: float) -> float:
    """``x / n`` with numpy's IEEE result for ``n == 0`` (NaN for 0 / 0, signed infinity else)."""
    if n != 0.0:
        return x / n
    return math.nan if x == 0.0 or x != x else math.copysign(math.inf, x)


def unit3(v: Vec) -> Vec:
    """``v`` over its length (``segments._unit`` of a (3,) vector; NaN where it is 0)."""
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return _div(v[0], n), _div(v[1], n), _div(v[2], n)


def angle3_deg(a: Vec, b: Vec) -> float:
    """The angle between vectors ``a`` and ``b`` (any lengths), degrees: ``frames.angle_deg``
    (``atan2`` of the cross and dot products)."""
    cx, cy, cz = a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]
    return math.degrees(math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), a[0] * b[0] + a[1] * b[1] + a[2] * b[2]))


def _median(col: list[float]) -> float:
    """``np.median`` of a list of floats (NaN if any is NaN; the mean of the middle two if even)."""
    total = sum(col)
    if total != total and any(x != x for x in col):        # NaN (the sum alone: also inf - inf)
        return math.nan
    col.sort()
    n = len(col)
    return col[n // 2] if n % 2 else (col[n // 2 - 1] + col[n // 2]) / 2


def median3(rows: Sequence[Vec]) -> Vec:
    """The per-axis median of vectors ``rows`` (at least one): ``np.median(rows, axis=0)``."""
    return (_median([r[0] for r in rows]), _median([r[1] for r in rows]), _median([r[2] for r in rows]))


def add3(a: Vec, b: Vec) -> Vec:
    """``a + b``."""
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


def window_median(items: Sequence[tuple]) -> tuple[Vec | None, Vec]:
    """(median origin, or None when any is None; unit median direction) of samples ``items``
    ((unit direction, origin mm or None, ...), at least one): the median ray of a window of the
    online segmenter (``np.median(..., axis=0)`` of each, the direction then made unit)."""
    origin = None if any(x[1] is None for x in items) else median3([x[1] for x in items])
    return origin, unit3(median3([x[0] for x in items]))


def _nanmin(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN if either is)."""
    return a if (a <= b or a != a) else b


def world_jump3_deg(o_a: Vec, d_a: Vec, o_b: Vec, d_b: Vec, min_depth_mm: float,
                    max_depth_mm: float = math.inf) -> float:
    """``segdepth.world_jump_deg`` of one pair of rays, degrees: the least angle between the unit
    direction ``d_b`` from origin ``o_b`` and the directions from ``o_b`` to the points of the ray
    ``(o_a, d_a)`` (unit ``d_a``) from ``min_depth_mm`` to ``max_depth_mm`` along it (world frame,
    mm; not finite: to infinity)."""
    u0 = _toward(o_a, d_a, o_b, min_depth_mm)
    u1 = _toward(o_a, d_a, o_b, max_depth_mm) if math.isfinite(max_depth_mm) else d_a
    m = (u0[1] * u1[2] - u0[2] * u1[1], u0[2] * u1[0] - u0[0] * u1[2], u0[0] * u1[1] - u0[1] * u1[0])
    mn = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    c1 = (u0[1] * d_b[2] - u0[2] * d_b[1], u0[2] * d_b[0] - u0[0] * d_b[2], u0[0] * d_b[1] - u0[1] * d_b[0])
    c2 = (d_b[1] * u1[2] - d_b[2] * u1[1], d_b[2] * u1[0] - d_b[0] * u1[2], d_b[0] * u1[1] - d_b[1] * u1[0])
    inside = ((c1[0] * m[0] + c1[1] * m[1] + c1[2] * m[2]) >= 0 and (c2[0] * m[0] + c2[1] * m[1] + c2[2] * m[2]) >= 0
              and mn > 1e-12)
    if not inside:
        return _nanmin(angle3_deg(d_b, u0), angle3_deg(d_b, u1))
    s = abs(d_b[0] * m[0] + d_b[1] * m[1] + d_b[2] * m[2]) / mn
    return math.degrees(math.asin(min(max(s, 0.0), 1.0)))


def _toward(o_a: Vec, d_a: Vec, o_b: Vec, depth_mm: float) -> Vec:
    """The unit direction from ``o_b`` to the point ``depth_mm`` along the ray ``(o_a, d_a)``."""
    u = (o_a[0] - o_b[0] + depth_mm * d_a[0], o_a[1] - o_b[1] + depth_mm * d_a[1],
         o_a[2] - o_b[2] + depth_mm * d_a[2])
    un = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    return _div(u[0], un), _div(u[1], un), _div(u[2], un)


def second_angle3_deg(o0: Vec | None, d0: Vec, o1: Vec | None, d1: Vec, o2: Vec | None, d2: Vec,
                      min_depth_mm: float) -> float:
    """``segments._second_angles`` of one triple of rays, degrees: the angle between the unit
    direction ``d1`` and the direction from ``o1`` to the nearest approach of the rays
    ``(o0, d0)`` and ``(o2, d2)`` when it is ``min_depth_mm`` or farther along both (world frame,
    mm), else (or with an origin None or not finite) the sum of ``d0`` and ``d2``."""
    aim = (d0[0] + d2[0], d0[1] + d2[1], d0[2] + d2[2])
    if (o0 is not None and o1 is not None and o2 is not None
            and math.isfinite(o1[0]) and math.isfinite(o1[1]) and math.isfinite(o1[2])):
        b = d0[0] * d2[0] + d0[1] * d2[1] + d0[2] * d2[2]
        base = (o0[0] - o2[0], o0[1] - o2[1], o0[2] - o2[2])
        e0 = d0[0] * base[0] + d0[1] * base[1] + d0[2] * base[2]
        e2 = d2[0] * base[0] + d2[1] * base[1] + d2[2] * base[2]
        den = 1 - b * b
        s0, s2 = _div(b * e2 - e0, den), _div(e2 - b * e0, den)
        point = [0.5 * (o0[i] + s0 * d0[i] + o2[i] + s2 * d2[i]) for i in range(3)]
        if (math.isfinite(point[0]) and math.isfinite(point[1]) and math.isfinite(point[2])
                and s0 >= min_depth_mm and s2 >= min_depth_mm):
            aim = (point[0] - o1[0], point[1] - o1[1], point[2] - o1[2])
    return angle3_deg(d1, aim)


class SlidingQuantile:
    """The last ``maxlen`` values appended (floats), kept sorted too, so that a quantile of them
    costs O(1) and an append O(maxlen) in a memory move: ``quantile`` and ``median`` are
    ``np.quantile`` (its default, linear method) and ``np.median`` of those values, bit for bit
    (NaN while any of them is NaN)."""

    def __init__(self, maxlen: int):
        self.values: deque[float] = deque(maxlen=maxlen)   # in the order appended
        self.sorted: list[float] = []                       # the values but NaN, ascending
        self.n_nan = 0

    def __len__(self) -> int:
        return len(self.values)

    def append(self, x: float) -> None:
        """Add ``x``, dropping the oldest value when ``maxlen`` are kept."""
        if len(self.values) == self.values.maxlen:
            old = self.values[0]
            if old != old:
                self.n_nan -= 1
            else:
                del self.sorted[bisect_left(self.sorted, old)]
        self.values.append(x)
        if x != x:
            self.n_nan += 1
        else:
            insort(self.sorted, x)

    def quantile(self, q: float) -> float:
        """``np.quantile(values, q)`` (0 <= q <= 1; at least one value): the linear interpolation
        between the sorted values around index ``(n - 1) q``, as numpy's ``_lerp`` computes it."""
        if self.n_nan:
            return math.nan
        s = self.sorted
        v = (len(s) - 1) * q
        if v >= len(s) - 1:
            return s[-1]
        i = math.floor(v)
        a, b, t = s[i], s[i + 1], v - i
        return b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t

    def median(self) -> float:
        """``np.median(values)`` (at least one value)."""
        if self.n_nan:
            return math.nan
        s, n = self.sorted, len(self.sorted)
        return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) / 2


def lines3(origins: Any, directions: Any) -> tuple[Line, ...]:
    """One sample's lines, origins (E, 3), mm, and unit directions (E, 3) (NaN: invalid), as
    ``Line`` pairs."""
    o, d = (x.tolist() if hasattr(x, "tolist") else x for x in (origins, directions))
    return tuple((vec3(a), vec3(b)) for a, b in zip(o, d, strict=True))


def _finite3(v: Vec) -> bool:
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


class LineSums3:
    """``segdepth.LineSums`` in plain floats: ``segdepth.line_terms`` summed over a stream of
    samples relative to the first finite line origin (``A``: row-major 3x3, ``b``, ``c``, ``n``),
    and the depths the lines fix along a ray (``bounds``: ``segdepth.depth_bounds``)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.center: Vec | None = None
        self.A, self.b, self.c, self.n = [0.0] * 9, [0.0] * 3, 0.0, 0

    def add(self, lines: Sequence[Line]) -> None:
        """Add one sample's lines (``lines3``); the lines with a NaN are skipped."""
        if self.center is None:
            self.center = next((o for o, _ in lines if _finite3(o)), None)
            if self.center is None:
                return
        cx, cy, cz = self.center
        A, b = self.A, self.b
        for o, d in lines:
            ox, oy, oz = o[0] - cx, o[1] - cy, o[2] - cz
            dx, dy, dz = d
            if not (_finite3((ox, oy, oz)) and _finite3(d)):
                continue
            p = (1.0 - dx * dx, -(dx * dy), -(dx * dz), -(dy * dx), 1.0 - dy * dy, -(dy * dz),
                 -(dz * dx), -(dz * dy), 1.0 - dz * dz)                       # I - d d^T
            po = (p[0] * ox + p[1] * oy + p[2] * oz, p[3] * ox + p[4] * oy + p[5] * oz,
                  p[6] * ox + p[7] * oy + p[8] * oz)
            for i in range(9):
                A[i] += p[i]
            b[0], b[1], b[2] = b[0] + po[0], b[1] + po[1], b[2] + po[2]
            self.c += ox * po[0] + oy * po[1] + oz * po[2]
            self.n += 1

    def bounds(self, o_a: Vec, d_a: Vec, noise_deg: float, min_depth_mm: float) -> tuple[float, float]:
        """(near, far) depths, mm, along the ray ``(o_a, d_a)`` (world, unit ``d_a``) of the point
        the lines fix (``segdepth.depth_bounds`` at per-line noise ``noise_deg``, degrees):
        (``min_depth_mm``, inf) with fewer than 3 lines or a point not ahead."""
        none = (float(min_depth_mm), math.inf)
        if self.center is None or self.n < 3:
            return none
        A, n = self.A, self.n
        reg = 1e-9 * (A[0] + A[4] + A[8])
        lu = _lu3([A[0] + reg, A[1], A[2], A[3], A[4] + reg, A[5], A[6], A[7], A[8] + reg])
        if lu is None:
            return none
        X = _lu_solve3(lu, self.b)
        AX = [A[3 * i] * X[0] + A[3 * i + 1] * X[1] + A[3 * i + 2] * X[2] for i in range(3)]
        rss = _nanmax(X[0] * AX[0] + X[1] * AX[1] + X[2] * AX[2]
                      - 2 * (X[0] * self.b[0] + X[1] * self.b[1] + X[2] * self.b[2]) + self.c, 0.0)
        c = self.center
        v = (X[0] - (o_a[0] - c[0]), X[1] - (o_a[1] - c[1]), X[2] - (o_a[2] - c[2]))
        rho = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if not (rho > 0 and math.isfinite(rho) and v[0] * d_a[0] + v[1] * d_a[1] + v[2] * d_a[2] > 0):
            return none
        u = (v[0] / rho, v[1] / rho, v[2] / rho)
        y = _lu_solve3(lu, u)
        g = math.sqrt(_nanmax(u[0] * y[0] + u[1] * y[1] + u[2] * y[2], 0.0)) / rho
        sigma, bias = math.radians(noise_deg), math.radians(BIAS_DEG)
        inflate = _nanmax(1.0, rss / (sigma * rho) ** 2 / max(2 * n - 3, 1))
        half = g * (DEPTH_K * sigma * math.sqrt(inflate) + bias * math.sqrt(n))
        if not math.isfinite(half):
            return none
        q = 1.0 / rho
        near = max(float(min_depth_mm), 1.0 / (q + half))
        return near, (max(1.0 / (q - half), near) if q > half else math.inf)


def _nanmax(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN if either is)."""
    return a if (a >= b or a != a) else b


def _lu3(m: list[float]) -> tuple[list[int], list[list[float]]] | None:
    """The LU factors of the row-major 3x3 ``m`` with partial pivoting (LAPACK ``getrf``'s
    order: (row order, rows of L below and U on and above the diagonal)); None if singular."""
    a, perm = [m[0:3], m[3:6], m[6:9]], [0, 1, 2]
    for k in range(3):
        p = max(range(k, 3), key=lambda i: abs(a[i][k]))
        if a[p][k] == 0.0 or a[p][k] != a[p][k]:
            return None
        if p != k:
            a[k], a[p], perm[k], perm[p] = a[p], a[k], perm[p], perm[k]
        r = 1.0 / a[k][k]
        for i in range(k + 1, 3):
            a[i][k] *= r
            for j in range(k + 1, 3):
                a[i][j] -= a[i][k] * a[k][j]
    return perm, a


def _lu_solve3(lu: tuple[list[int], list[list[float]]], rhs: Sequence[float]) -> Vec:
    """The solution x of ``m x = rhs`` from ``_lu3``'s factors of ``m``."""
    perm, a = lu
    y0 = rhs[perm[0]]
    y1 = rhs[perm[1]] - a[1][0] * y0
    y2 = rhs[perm[2]] - a[2][0] * y0 - a[2][1] * y1
    x2 = y2 / a[2][2]
    x1 = (y1 - a[1][2] * x2) / a[1][1]
    return (y0 - a[0][1] * x1 - a[0][2] * x2) / a[0][0], x1, x2
