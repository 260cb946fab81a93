"""Geometry the planners share: boxes, the TF alert-box forecast, Bezier curves, polynomial profiles."""

from __future__ import annotations

from math import comb

import numpy as np


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Corners [..., 4, 2] of boxes centred at (x, y) with the given heading and size."""
    x, y, heading, length, width = np.broadcast_arrays(*map(np.asarray, (x, y, heading, length, width)))
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    lx = np.array([0.5, 0.5, -0.5, -0.5]) * length[..., None]
    ly = np.array([0.5, -0.5, -0.5, 0.5]) * width[..., None]
    return np.stack([x[..., None] + c * lx - s * ly, y[..., None] + s * lx + c * ly], axis=-1)


def collision_forecast(
    ego_speed: float,
    ego_length: float,
    ego_width: float,
    nb_xy: np.ndarray,
    nb_heading: np.ndarray,
    nb_speed: np.ndarray,
    nb_length: np.ndarray,
    nb_width: np.ndarray,
    l_front: float,
    w_left: float = 1.25,
    w_right: float = 1.25,
    steps: int = 5,
    dt: float = 0.1,
) -> np.ndarray:
    """TF's alert-box test, in the ego frame at t = 0 (ego at the origin heading +x).

    Both move at constant speed along their headings, sampled at t = 0, dt, ..., steps*dt. The
    ego's alert rectangle spans its rear bumper to ``l_front`` beyond its front bumper and
    ``width/2 + w_left`` left, ``width/2 + w_right`` right. A neighbour hits when any of its four
    corners lies inside the rectangle at any sample (corner-in-rectangle, not SAT).
    Returns bool [N], one per neighbour."""
    nb_xy = np.asarray(nb_xy, dtype=np.float64).reshape(-1, 2)
    if len(nb_xy) == 0:
        return np.zeros(0, dtype=bool)
    t = np.arange(steps + 1) * dt  # [S]
    nx = nb_xy[:, 0:1] + np.cos(nb_heading)[:, None] * nb_speed[:, None] * t  # [N, S]
    ny = nb_xy[:, 1:2] + np.sin(nb_heading)[:, None] * nb_speed[:, None] * t
    corners = box_corners(
        nx,
        ny,
        np.broadcast_to(np.asarray(nb_heading)[:, None], nx.shape),
        np.broadcast_to(np.asarray(nb_length)[:, None], nx.shape),
        np.broadcast_to(np.asarray(nb_width)[:, None], nx.shape),
    )  # [N, S, 4, 2]
    ex = ego_speed * t[None, :, None]  # ego centre moves along +x
    rel_x = corners[..., 0] - ex
    inside = (
        (rel_x >= -0.5 * ego_length) & (rel_x <= 0.5 * ego_length + l_front)
        & (corners[..., 1] <= 0.5 * ego_width + w_left) & (corners[..., 1] >= -0.5 * ego_width - w_right)
    )  # fmt: skip
    return inside.any(axis=(1, 2))


# ----------------------------------------------------------------------------- Bezier curves
def bezier_points(control: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points [T, 2] of the Bezier curve of degree n-1 over ``control`` [n, 2] at parameters t."""
    control = np.asarray(control, dtype=np.float64)
    n = len(control) - 1
    t = np.asarray(t, dtype=np.float64)[:, None]
    k = np.arange(n + 1)
    binom = np.array([comb(n, i) for i in k], dtype=np.float64)
    basis = binom * t**k * (1 - t) ** (n - k)  # [T, n+1]
    return basis @ control


def bezier_tangents(control: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Derivatives [T, 2] (the hodograph) of the Bezier curve at parameters t."""
    control = np.asarray(control, dtype=np.float64)
    n = len(control) - 1
    if n == 0:
        return np.zeros((len(np.atleast_1d(t)), 2))
    return n * bezier_points(np.diff(control, axis=0), t)


def bezier_length(control: np.ndarray, samples: int = 256) -> float:
    """Arc length of the Bezier curve (Gauss-Legendre quadrature of the hodograph's norm)."""
    nodes, weights = np.polynomial.legendre.leggauss(64)
    t = 0.5 * (nodes + 1.0)
    speed = np.linalg.norm(bezier_tangents(control, t), axis=1)
    return float(0.5 * np.sum(weights * speed))


# ----------------------------------------------------------------------------- polynomial profiles
def cubic_coefficients(x0: float, v0: float, x1: float, v1: float, T: float) -> np.ndarray:
    """c0..c3 of x(t) = sum c_i t^i with x(0)=x0, x'(0)=v0, x(T)=x1, x'(T)=v1."""
    a = np.array([[T**2, T**3], [2 * T, 3 * T**2]])
    b = np.array([x1 - x0 - v0 * T, v1 - v0])
    c2, c3 = np.linalg.solve(a, b)
    return np.array([x0, v0, c2, c3])


def quintic_coefficients(x0: float, v0: float, a0: float, x1: float, v1: float, a1: float, T: float) -> np.ndarray:
    """c0..c5 of x(t) with position, velocity and acceleration fixed at t = 0 and t = T."""
    a = np.array([
        [T**3, T**4, T**5],
        [3 * T**2, 4 * T**3, 5 * T**4],
        [6 * T, 12 * T**2, 20 * T**3],
    ])  # fmt: skip
    b = np.array([x1 - x0 - v0 * T - 0.5 * a0 * T**2, v1 - v0 - a0 * T, a1 - a0])
    return np.concatenate([[x0, v0, 0.5 * a0], np.linalg.solve(a, b)])


def polyval(coefficients: np.ndarray, t: np.ndarray, derivative: int = 0) -> np.ndarray:
    """Value (or a derivative) of sum c_i t^i at t."""
    c = np.polynomial.polynomial.Polynomial(coefficients)
    return c.deriv(derivative)(t) if derivative else c(t)
