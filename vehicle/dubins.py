"""Shortest forward-only turns of bounded curvature (Dubins paths) between two poses.

A tractor that cannot reverse joins the end of one swath to the start of the next with one of six
words of Left/Right arcs and Straights. Between swaths farther apart than twice the turning radius
the shortest word is the U-turn LSL/RSR; closer swaths give LRL/RLR, the bulb ("light bulb" or
omega) turn. Formulas after Shkel & Lumelsky (2001), as in A. Walker's ``dubins`` library.
"""

from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi


def _mod(a: float) -> float:
    return a - _TWO_PI * math.floor(a / _TWO_PI)


def _words(alpha: float, beta: float, d: float):
    """Yield (word, (t, p, q)) for each feasible word; t, p, q in units of the turning radius."""
    sa, sb, ca, cb = math.sin(alpha), math.sin(beta), math.cos(alpha), math.cos(beta)
    c_ab = math.cos(alpha - beta)
    p2 = 2 + d * d - 2 * c_ab + 2 * d * (sa - sb)
    if p2 >= 0:
        tmp = math.atan2(cb - ca, d + sa - sb)
        yield "LSL", (_mod(-alpha + tmp), math.sqrt(p2), _mod(beta - tmp))
    p2 = 2 + d * d - 2 * c_ab + 2 * d * (sb - sa)
    if p2 >= 0:
        tmp = math.atan2(ca - cb, d - sa + sb)
        yield "RSR", (_mod(alpha - tmp), math.sqrt(p2), _mod(-beta + tmp))
    p2 = -2 + d * d + 2 * c_ab + 2 * d * (sa + sb)
    if p2 >= 0:
        p = math.sqrt(p2)
        tmp = math.atan2(-ca - cb, d + sa + sb) - math.atan2(-2.0, p)
        yield "LSR", (_mod(-alpha + tmp), p, _mod(-_mod(beta) + tmp))
    p2 = -2 + d * d + 2 * c_ab - 2 * d * (sa + sb)
    if p2 >= 0:
        p = math.sqrt(p2)
        tmp = math.atan2(ca + cb, d - sa - sb) - math.atan2(2.0, p)
        yield "RSL", (_mod(alpha - tmp), p, _mod(beta - tmp))
    tmp = (6.0 - d * d + 2 * c_ab + 2 * d * (sa - sb)) / 8.0
    if abs(tmp) <= 1:
        p = _mod(_TWO_PI - math.acos(tmp))
        t = _mod(alpha - math.atan2(ca - cb, d - sa + sb) + p / 2.0)
        yield "RLR", (t, p, _mod(alpha - beta - t + p))
    tmp = (6.0 - d * d + 2 * c_ab + 2 * d * (sb - sa)) / 8.0
    if abs(tmp) <= 1:
        p = _mod(_TWO_PI - math.acos(tmp))
        t = _mod(-alpha - math.atan2(ca - cb, d + sa - sb) + p / 2.0)
        yield "LRL", (t, p, _mod(_mod(beta) - alpha - t + p))


def _shortest_word(start, end, radius_m: float):
    """The shortest Dubins word from pose ``start`` to pose ``end``.

    Parameters
    ----------
    start, end : (x_m, y_m, heading_rad)
        Poses; heading in the math convention (counter-clockwise from +x).
    radius_m : float
        Minimum turning radius, m (> 0).

    Returns
    -------
    (word, lengths) : (str, tuple of 3 float)
        E.g. ``("LSL", (t, p, q))`` with the three lengths in radius units.
    """
    dx, dy = end[0] - start[0], end[1] - start[1]
    d = math.hypot(dx, dy) / radius_m
    theta = _mod(math.atan2(dy, dx)) if d > 0 else 0.0
    alpha, beta = _mod(start[2] - theta), _mod(end[2] - theta)
    return min(_words(alpha, beta, d), key=lambda wl: sum(wl[1]))


def dubins_xy(start, end, radius_m: float, step_m: float = 0.25) -> np.ndarray:
    """Sample the shortest Dubins path from ``start`` to ``end`` every <= ``step_m`` metres.

    Returns
    -------
    ndarray, shape (k, 2)
        Points from ``start`` to exactly ``end`` (both included), metres.
    """
    word, lengths = _shortest_word(start, end, radius_m)
    x, y, h = float(start[0]), float(start[1]), float(start[2])
    pieces = [np.array([[x, y]])]
    for kind, length in zip(word, lengths, strict=True):
        n = max(1, math.ceil(length * radius_m / step_m))
        a = np.linspace(0.0, length, n + 1)[1:]
        if kind == "S":
            px, py = x + radius_m * a * math.cos(h), y + radius_m * a * math.sin(h)
            h_end = h
        else:
            sign = 1.0 if kind == "L" else -1.0
            px = x + sign * radius_m * (np.sin(h + sign * a) - math.sin(h))
            py = y - sign * radius_m * (np.cos(h + sign * a) - math.cos(h))
            h_end = h + sign * length
        pieces.append(np.column_stack([px, py]))
        x, y, h = float(px[-1]), float(py[-1]), h_end
    xy = np.concatenate(pieces)
    xy[-1] = end[0], end[1]  # remove the ~1e-12 m integration residue so segments join exactly
    keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 1e-9])
    return xy[keep]
