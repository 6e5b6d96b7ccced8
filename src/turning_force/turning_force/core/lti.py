"""Small linear-systems helpers, numpy only: what the plant, the estimator and the predictor
need at set-up, once per object.

They replace scipy's ``cont2discrete``, ``lfiltic``, ``expm`` and ``solve_discrete_are``, whose
imports (``scipy.signal`` alone 0.7-0.9 s) would otherwise land on every start-up.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ['expm', 'kalman_gain', 'lfiltic', 'zoh']

FloatArray = npt.NDArray[np.float64]


def expm(a: FloatArray) -> FloatArray:
    """Matrix exponential by scaling and squaring a Taylor series (small matrices; accurate
    to a few units in the last place for the norms met here)."""
    a = np.asarray(a, dtype=np.float64)
    norm = float(np.max(np.sum(np.abs(a), axis=1))) if a.size else 0.0
    squarings = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    scaled = a / 2.0**squarings
    term = np.eye(a.shape[0])
    out = term.copy()
    for k in range(1, 20):
        term = term @ scaled / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out


def zoh(num: Sequence[float], den: Sequence[float],
        dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact zero-order-hold discretisation of the strictly proper ``num(s) / den(s)``:
    ``(numd, dend)`` with ``dend[0] == 1``, both of ``len(den)`` coefficients. Cached: a sweep
    sets up the same plant many times."""
    numd, dend = _zoh(tuple(float(v) for v in num), tuple(float(v) for v in den), float(dt_s))
    return numd.copy(), dend.copy()


@functools.lru_cache(maxsize=64)
def _zoh(num: tuple[float, ...], den: tuple[float, ...],
         dt_s: float) -> tuple[FloatArray, FloatArray]:
    den_a = np.asarray(den, dtype=np.float64)
    num_a = np.asarray(num, dtype=np.float64) / den_a[0]
    den_a = den_a / den_a[0]
    n = den_a.size - 1
    # Controllable canonical form.
    a = np.zeros((n, n))
    a[0, :] = -den_a[1:]
    a[1:, :-1] = np.eye(n - 1)
    b = np.zeros(n)
    b[0] = 1.0
    c = np.zeros(n)
    c[n - num_a.size:] = num_a
    block = np.zeros((n + 1, n + 1))
    block[:n, :n], block[:n, n] = a * dt_s, b * dt_s
    e = expm(block)
    ad, bd = e[:n, :n], e[:n, n]
    # H(z) = c (zI - Ad)^-1 bd = (det(zI - Ad + bd c) - det(zI - Ad)) / det(zI - Ad).
    dend = np.real(np.poly(ad))
    numd = np.real(np.poly(ad - np.outer(bd, c))) - dend
    numd[0] = 0.0
    return numd, dend


def lfiltic(b: FloatArray, a: FloatArray, y: Sequence[float],
            x: Sequence[float]) -> FloatArray:
    """Initial state of a direct-form-II-transposed filter (``a[0] == 1``) from past outputs
    ``y`` and inputs ``x``, most recent first (scipy's ``lfiltic``)."""
    size = max(len(a), len(b)) - 1
    zi = np.zeros(size)
    for m in range(size):
        zi[m] = sum(float(b[m + 1 + j]) * x[j] for j in range(len(b) - 1 - m)) \
            - sum(float(a[m + 1 + j]) * y[j] for j in range(len(a) - 1 - m))
    return zi


@functools.lru_cache(maxsize=64)
def kalman_gain(dt_s: float, accel_noise: float, measurement_noise: float) -> tuple[float, float]:
    """Steady-state gain of the Kalman filter for ``x = [F, dF/dt]`` under white force
    acceleration (``phi = [[1, dt], [0, 1]]``, ``Q = s_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]``,
    ``H = [1, 0]``, ``R = s_F^2``): the prior covariance solves the discrete Riccati equation,
    here by the structure-preserving doubling algorithm (quadratic convergence). Cached: a
    sweep sets up the same filter many times."""
    phi = np.array([[1.0, dt_s], [0.0, 1.0]])
    q = accel_noise**2 * np.array([[dt_s**4 / 4, dt_s**3 / 2], [dt_s**3 / 2, dt_s**2]])
    r = measurement_noise**2
    a, g, h = phi.T, np.array([[1.0 / r, 0.0], [0.0, 0.0]]), q
    for _ in range(100):
        w = np.linalg.inv(np.eye(2) + g @ h)
        a, g, h_next = a @ w @ a, g + a @ w @ g @ a.T, h + a.T @ h @ w @ a
        if np.all(np.abs(h_next - h) <= 1e-15 * np.abs(h_next)):
            h = h_next
            break
        h = h_next
    return float(h[0, 0] / (h[0, 0] + r)), float(h[1, 0] / (h[0, 0] + r))
