"""The simulated lathe, compiled: PMC dead time, CNC servo, cutting process and feed-drive
currents, one control block at a time (:mod:`turning_force.core.plant.settings` states the model
and its settings). """

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from turning_force.core import lti
from turning_force.core.compiled import Arr, activate, compiled, delayed, entry, pymin, pymod
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.plant.feeddrive import friction_current
from turning_force.core.plant.settings import PlantBlock, PlantSettings

__all__ = ['TRUTH_ROWS', 'LathePlant', 'commanded_rate', 'plant_step', 'spindle_rpm']

FloatArray = npt.NDArray[np.float64]
_SQRT3 = math.sqrt(3.0)
_TWO_PI = 2.0 * math.pi

# --- plant parameters -----------------------------------------------------------------------
P_N, P_DT, P_FEED_RATE, P_RPM, P_K, P_G, P_PROCESS, P_NOISE, P_FNOISE = range(9)
P_FAULT_START, P_FAULT_DUR, P_ANGLE_C, P_PITCH = range(9, 13)
P_FR_A, P_FR_B, P_FR_MIN, P_FR_MAX, P_MAP_OFF, P_MAP_PER = range(13, 19)
P_SERVO_LEN, P_SB, P_SA = 19, 20, 23          # b and a: 3 slots each
P_PB, P_PA, P_DELAY, P_LINEAR, P_FEED_NOISE = 26, 28, 30, 31, 32
# constant surface speed (G96): V [m/min] (0: off), the start diameter, the clamp (G50 S), and
# the programmed feed [mm/rev]; the machine not following the override: [start, end) of override
# cancel (M49), feed hold and dry run, and the dry-run feed rate
P_CSS, P_CSS_D0, P_RPM_MAX, P_FEED_REV = 33, 34, 35, 36
P_CANCEL, P_HOLD, P_DRY, P_DRY_RATE = 37, 39, 41, 43
P_SPEED_WIRED = 44   # the spindle speed input (machine/spindle_speed) wired
# the program's tool changes: how many, then (time [s], k, g) of each from P_TOOL_AT on (the
# material each tool meets: its k and g from its time on); none: P_K and P_G throughout
P_TOOLS, P_TOOL_AT = 45, 46
P_SIZE = 46
# truth rows: force, depth, feed [mm/rev], spindle speed [rpm]
TRUTH_ROWS = 4
# plant state
PS_POS, PS_K, PS_QIDX, PS_SZ, PS_PZ, PS_QUEUE = 0, 1, 2, 3, 5, 6


# --- the plant (core/plant.py LathePlant.step) ----------------------------------------------

@compiled
def spindle_rpm(pp: np.ndarray, position_mm: float) -> float:
    """The spindle speed [rpm]: ``spindle_speed_rpm``, or under constant surface speed (G96)
    a facing cut's, ``N = 1000 V / (pi D)`` with ``D = D0 - 2 x`` (the feed axis is the cross
    slide: its travel x [mm] takes the diameter down by twice as much), clamped at the largest
    speed the program allows (G50 S)."""
    if pp[P_CSS] <= 0.0:
        return pp[P_RPM]
    diameter = pp[P_CSS_D0] - 2.0 * position_mm
    if diameter <= 0.0:
        return pp[P_RPM_MAX]
    return pymin(1000.0 * pp[P_CSS] / (math.pi * diameter), pp[P_RPM_MAX])


@compiled
def _within(pp: np.ndarray, span: int, t: float) -> bool:
    return pp[span] <= t < pp[span + 1]


@compiled
def commanded_rate(pp: np.ndarray, t: float, override_pct: float, rpm: float) -> float:
    """The axis feed rate the CNC commands [mm/min] for the override the PMC was written: the
    programmed feed per revolution at the override (G95) and the spindle speed, unless the
    machine does not follow the override: a dry run (the dry-run rate, whatever the override),
    a feed hold (0), override cancel (M49, or a ladder that never copies the module's inputs to
    *FV: 100 %)."""
    if _within(pp, P_DRY, t):
        return pp[P_DRY_RATE]
    if _within(pp, P_HOLD, t):
        return 0.0
    pct = 100.0 if _within(pp, P_CANCEL, t) else override_pct
    if pp[P_CSS] > 0.0:
        return pct / 100.0 * pp[P_FEED_REV] * rpm
    return pct / 100.0 * pp[P_FEED_RATE]


@compiled
def depth_at(times: np.ndarray, depths: np.ndarray, linear: bool, t: float) -> float:
    """DepthProfile.at: held steps (searchsorted right) or np.interp."""
    m = times.size
    if not linear:
        index = 0
        while index < m and times[index] <= t:
            index += 1
        index -= 1
        return depths[min(max(index, 0), m - 1)]
    if t < times[0]:
        return depths[0]
    if t >= times[m - 1]:
        return depths[m - 1]
    j = 0
    while times[j + 1] <= t:
        j += 1
    slope = (depths[j + 1] - depths[j]) / (times[j + 1] - times[j])
    out = slope * (t - times[j]) + depths[j]
    if out != out:
        out = slope * (t - times[j + 1]) + depths[j + 1]
        if out != out and depths[j] == depths[j + 1]:
            out = depths[j]
    return out


@compiled
def _material(pp: np.ndarray, t: float) -> tuple[float, float]:
    """The process gain k and exponent g the tool in use at ``t`` meets (the program's tool
    changes, P_TOOLS; none: P_K and P_G)."""
    k, g = pp[P_K], pp[P_G]
    for j in range(int(pp[P_TOOLS])):
        at = P_TOOL_AT + 3 * j
        if pp[at] > t:
            break
        k, g = pp[at + 1], pp[at + 2]
    return k, g


@compiled
def plant_step(pp: np.ndarray, ps: np.ndarray, times: np.ndarray, depths: np.ndarray,
               override_pct: float, noise_u: np.ndarray, noise_v: np.ndarray,
               noise_f: np.ndarray, noise_fr: np.ndarray, lo: int, u: np.ndarray,
               v: np.ndarray, angle: np.ndarray, feed_rate: np.ndarray,
               truth: np.ndarray) -> float:
    """The lathe for one block at ``override_pct`` (the one source of the simulated plant:
    :class:`turning_force.core.plant.lathe.LathePlant` steps it too).

    override -> PMC dead time (a ring of ``P_DELAY`` samples) -> CNC servo (Park Eq. 2, first
    order, or Hwang & Chen Eq. 1, second order; zero-order-hold coefficients in direct form II
    transposed) -> feed [mm/rev] -> cutting force F = k d f^g through the process lag tau_c
    (Park Eq. 1; Hwang & Chen Eq. 3) -> q-axis current (Park Eq. 26) plus friction (Park
    Eq. 25) -> u, v phase currents at the rotor angle, plus sensor noise.

    The DAQ's arrays into u, v, angle, feed_rate (the measured feed rate: ``noise_fr`` added
    where ``P_FEED_NOISE``); the true force, depth, feed [mm/rev] and spindle speed [rpm] of
    every sample into rows 0-3 of ``truth`` (TRUTH_ROWS, n); returns the block's t0. Noise
    samples are read from ``lo`` on (drawn in Python from the plant's own Generator)."""
    n = int(pp[P_N])
    dt = pp[P_DT]
    k = int(ps[PS_K])
    rpm = spindle_rpm(pp, ps[PS_POS])
    commanded = commanded_rate(pp, float(k) * dt, override_pct, rpm)
    css = pp[P_CSS] > 0.0
    delay = int(pp[P_DELAY])
    order = int(pp[P_SERVO_LEN]) - 1
    sb0, sb1, sb2 = pp[P_SB], pp[P_SB + 1], pp[P_SB + 2]
    sa1, sa2 = pp[P_SA + 1], pp[P_SA + 2]
    z0, z1 = ps[PS_SZ], ps[PS_SZ + 1]
    pz = ps[PS_PZ]
    pb0, pb1, pa1 = pp[P_PB], pp[P_PB + 1], pp[P_PA + 1]
    cumulative = 0.0
    position0 = ps[PS_POS]
    fault_end = pp[P_FAULT_START] + pp[P_FAULT_DUR]
    linear = pp[P_LINEAR] != 0.0
    position = position0
    for i in range(n):
        t = float(k + i) * dt
        if css:
            rpm = spindle_rpm(pp, position)
            commanded = commanded_rate(pp, float(k) * dt, override_pct, rpm)
        servo_in = delayed(ps, PS_QUEUE, PS_QIDX, delay, commanded)
        # Direct form II transposed (scipy's lfilter), a[0] == 1.
        if order == 1:
            fr = z0 + sb0 * servo_in
            z0 = sb1 * servo_in - sa1 * fr
        else:
            fr = z0 + sb0 * servo_in
            z0 = z1 + sb1 * servo_in - sa1 * fr
            z1 = sb2 * servo_in - sa2 * fr
        cumulative = fr if i == 0 else cumulative + fr
        position = position0 + cumulative * dt / 60.0
        depth = depth_at(times, depths, linear, t)
        feed = (fr if fr >= 0.0 or fr != fr else 0.0) / rpm
        k_cut, g = _material(pp, t)
        if g == 1.0:
            powered = feed
        elif g == 0.5:
            powered = math.sqrt(feed)
        elif g == 2.0:
            powered = feed * feed
        else:
            powered = feed ** g
        static = k_cut * depth * powered
        if pp[P_PROCESS] != 0.0:
            force = pz + pb0 * static
            pz = pb1 * static - pa1 * force
        else:
            force = static
        felt = force
        if pp[P_FNOISE] > 0.0:
            felt = force * (1.0 + noise_f[lo + i] * pp[P_FNOISE])
        current_q = (pp[P_MAP_OFF] + pp[P_MAP_PER] * felt) + friction_current(
            pp[P_FR_A], pp[P_FR_B], pp[P_FR_MIN], pp[P_FR_MAX], fr)
        theta = pymod(pp[P_ANGLE_C] * position / pp[P_PITCH], _TWO_PI)
        cos, sin = math.cos(theta), math.sin(theta)
        i_alpha = 0.0 * cos - current_q * sin
        i_beta = 0.0 * sin + current_q * cos
        pu = i_alpha
        pv = (-i_alpha + _SQRT3 * i_beta) / 2.0
        if pp[P_NOISE] > 0.0:
            pu = pu + noise_u[lo + i]
            pv = pv + noise_v[lo + i]
        if pp[P_FAULT_DUR] > 0.0 and t >= pp[P_FAULT_START] and t < fault_end:
            pu = math.nan
            pv = math.nan
        measured = fr + noise_fr[lo + i] if pp[P_FEED_NOISE] > 0.0 else fr
        u[i], v[i], angle[i], feed_rate[i] = pu, pv, theta, measured
        truth[0, i], truth[1, i], truth[2, i], truth[3, i] = force, depth, feed, rpm
    ps[PS_POS] = position
    ps[PS_SZ], ps[PS_SZ + 1], ps[PS_PZ] = z0, z1, pz
    ps[PS_K] = k + n
    return float(k) * dt


@entry('float64(float64[::1], float64[::1], float64[::1], float64[::1], float64, '
      'float64[::1], float64[::1], float64[::1], float64[::1], int64, float64[::1], '
      'float64[::1], float64[::1], float64[::1], float64[:, ::1])')
def plant_block(pp: Arr, ps: Arr, times: Arr, depths: Arr, override_pct: float, noise_u: Arr,
                noise_v: Arr, noise_f: Arr, noise_fr: Arr, lo: int, u: Arr, v: Arr, angle: Arr,
                feed_rate: Arr, truth: Arr) -> float:
    """:func:`plant_step` from Python (:class:`LathePlant`)."""
    return plant_step(pp, ps, times, depths, override_pct, noise_u, noise_v, noise_f, noise_fr,
                      lo, u, v, angle, feed_rate, truth)


class LathePlant:
    """The simulated lathe, stepped one control block at a time.

    At ``t = 0`` the axis is already feeding at the initial override (approach in air) and the
    tool enters the workpiece: the force starts at zero and rises with the process lag.
    Deterministic for given settings and seed.

    The arithmetic is one compiled function, :func:`plant_step` (the closed loop runs the same
    one on the arrays this object holds: :attr:`arrays`); this class draws the noise from its
    own generator, in one fixed order per block, and wraps the samples.
    """

    def __init__(self, settings: PlantSettings, samples_per_block: int | None = None,
                 initial_override_pct: float = 100.0) -> None:
        activate()   # compiled, not interpreted, from the first block
        self.settings = settings
        self.samples_per_block = samples_per_block or settings.samples_per_block
        self._dt = 1.0 / settings.sample_rate_hz
        self._rng = np.random.default_rng(settings.seed)
        self._params, self._state = _plant_arrays(settings, self.samples_per_block,
                                                  initial_override_pct)
        profile = settings.depth_profile
        self._times = np.asarray(profile.times_s, dtype=np.float64)
        self._depths = np.asarray(profile.depth_mm, dtype=np.float64)

    @property
    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(parameters, state, depth times, depths): what ``plant_step`` reads and writes (the
        state, live: a loop that steps them steps this plant)."""
        return self._params, self._state, self._times, self._depths

    @property
    def position_mm(self) -> float:
        """Feed-axis position at the end of the last block."""
        return float(self._state[PS_POS])

    def draw_noise(self, blocks: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The noise of the next ``blocks`` blocks, as ``plant_step`` reads it (u's and v's
        sensor noise, the force fluctuation, the feed reading's noise; each ``blocks x n`` long,
        or empty where that noise is off). Per block, in this order: the force fluctuation,
        u's and v's sensor noise, the feed reading's noise: a run gives the same numbers
        whatever the stretches it draws them in."""
        s, n, rng = self.settings, self.samples_per_block, self._rng
        normals = [s.current_noise_a] * (2 if s.current_noise_a > 0 else 0)
        if s.feed_noise_mm_min > 0:
            normals.append(s.feed_noise_mm_min)
        force = np.empty(0)
        drawn = np.empty((blocks, len(normals), n))
        if s.force_noise_fraction > 0:
            force = np.empty((blocks, n))
            for k in range(blocks):
                force[k] = rng.uniform(-1.0, 1.0, n)
                for j, sigma in enumerate(normals):
                    drawn[k, j] = rng.normal(0.0, sigma, n)
        elif normals and len(set(normals)) == 1:
            drawn = rng.normal(0.0, normals[0], (blocks, len(normals), n))
        else:
            for k in range(blocks):
                for j, sigma in enumerate(normals):
                    drawn[k, j] = rng.normal(0.0, sigma, n)
        empty = np.empty(0)
        columns = [np.ascontiguousarray(drawn[:, j, :]).ravel() for j in range(len(normals))]
        noise_u, noise_v = (columns[0], columns[1]) if s.current_noise_a > 0 else (empty, empty)
        noise_fr = columns[-1] if s.feed_noise_mm_min > 0 else empty
        return noise_u, noise_v, force.ravel(), noise_fr

    def step(self, override_pct: float) -> PlantBlock:
        """Apply ``override_pct`` for one block and return its samples."""
        s, n = self.settings, self.samples_per_block
        noise_u, noise_v, noise_f, noise_fr = self.draw_noise(1)
        u, v, angle, feed_rate = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        truth = np.empty((TRUTH_ROWS, n))
        t0 = plant_block(self._params, self._state, self._times, self._depths,
                         float(override_pct), noise_u, noise_v, noise_f, noise_fr, 0, u, v,
                         angle, feed_rate, truth)
        block = CurrentBlock(float(t0), self._dt, u, v, angle, feed_rate)
        speed = float(truth[3, -1])
        inputs = s.inputs_at(block.t0_s + n * self._dt)
        if s.spindle_speed_wired:
            inputs = replace(inputs, spindle_speed_rpm=speed)
        return PlantBlock(block, truth[0], truth[1], truth[2], override_pct, inputs, speed)


def _plant_arrays(s: PlantSettings, samples_per_block: int,
                  initial_override_pct: float) -> tuple[FloatArray, FloatArray]:
    """The plant's parameters (``P_*``) and its state (``PS_*``) at the start: the servo in
    steady state at the initial override, the PMC's queue full of it, no force."""
    dt = 1.0 / s.sample_rate_hz
    v0 = initial_override_pct / 100.0 * s.programmed_feed_rate_mm_min
    if s.css_surface_speed_m_min > 0:
        v0 = initial_override_pct / 100.0 * s.programmed_feed_mm_rev * s.start_spindle_speed_rpm
    if s.servo_model == 'first_order':
        sb, sa = lti.zoh([1.0], [s.servo_time_constant_s, 1.0], dt)
    else:
        wn, xi = s.servo_natural_freq_rad_s, s.servo_damping
        sb, sa = lti.zoh([wn**2], [1.0, 2 * xi * wn, wn**2], dt)
    delay = round(s.pmc_dead_time_s / dt)
    tools = len(s.tool_times_s) if s.tool_wired else 0
    p = np.zeros(P_SIZE + 3 * tools)
    p[P_TOOLS] = tools
    for j in range(tools):
        p[P_TOOL_AT + 3 * j:P_TOOL_AT + 3 * j + 3] = (
            s.tool_times_s[j], s.tool_specific_cutting_force_n_mm2[j], s.tool_cutting_exponent[j])
    p[P_N], p[P_DT] = samples_per_block, dt
    p[P_FEED_RATE], p[P_RPM] = s.programmed_feed_rate_mm_min, s.spindle_speed_rpm
    p[P_K], p[P_G] = s.specific_cutting_force_n_mm2, s.cutting_exponent
    p[P_NOISE], p[P_FNOISE] = s.current_noise_a, s.force_noise_fraction
    p[P_FEED_NOISE] = s.feed_noise_mm_min
    p[P_FAULT_START], p[P_FAULT_DUR] = s.sensor_fault_start_s, s.sensor_fault_duration_s
    p[P_ANGLE_C], p[P_PITCH] = 2.0 * math.pi * s.pole_pairs, s.ball_screw_pitch_mm
    f, m = s.friction, s.current_map
    p[P_FR_A], p[P_FR_B] = f.a_a_per_mm_min2, f.b_a
    p[P_FR_MIN], p[P_FR_MAX] = f.min_feed_mm_min, f.max_feed_mm_min
    p[P_MAP_OFF], p[P_MAP_PER] = m.offset_a, m.per_force_a_n
    p[P_SERVO_LEN] = sa.size
    p[P_SB:P_SB + sb.size], p[P_SA:P_SA + sa.size] = sb, sa
    p[P_DELAY] = delay
    p[P_LINEAR] = s.depth_interpolation == 'linear'
    p[P_CSS], p[P_CSS_D0] = s.css_surface_speed_m_min, s.css_start_diameter_mm
    p[P_RPM_MAX], p[P_FEED_REV] = s.css_max_spindle_rpm, s.programmed_feed_mm_rev
    p[P_CANCEL:P_CANCEL + 2] = s.override_cancel_span_s
    p[P_HOLD:P_HOLD + 2] = s.feed_hold_span_s
    p[P_DRY:P_DRY + 2] = s.dry_run_span_s
    p[P_DRY_RATE] = s.dry_run_feed_mm_min
    p[P_SPEED_WIRED] = s.spindle_speed_wired
    state = np.zeros(PS_QUEUE + delay)
    # The servo's steady state at v0: its output v0 for a constant input v0 (unit DC gain).
    zi = lti.lfiltic(sb, sa, [v0] * sa.size, [v0 / float(np.sum(sb) / np.sum(sa))] * sb.size)
    state[PS_SZ:PS_SZ + zi.size] = zi
    state[PS_QUEUE:] = v0
    tau_c = s.cutting_time_constant_s
    if tau_c > 0:
        pb, pa = lti.zoh([1.0], [tau_c, 1.0], dt)
        p[P_PROCESS] = 1.0
        p[P_PB:P_PB + 2], p[P_PA:P_PA + 2] = pb, pa
    return p, state
