"""The feed drive's equations the compiled plant and estimator share."""

from __future__ import annotations

from turning_force.core.compiled import compiled, npsign

__all__ = ['friction_current']


@compiled
def friction_current(a: float, b: float, vmin: float, vmax: float, feed: float) -> float:
    """FrictionModel.current_a at one feed rate (Park Eq. 25)."""
    speed = abs(feed)
    v = speed if speed >= vmin or speed != speed else vmin     # np.clip: max, then min
    v = v if v <= vmax or v != v else vmax
    d = v - vmin
    quadratic = a * (d * d) + b
    stick = speed / vmin
    stick = stick if stick <= 1.0 or stick != stick else 1.0  # np.minimum(x, 1)
    return npsign(feed) * stick * quadratic
