"""The force estimator, compiled: Clarke-Park, friction (Park Eq. 25), the current map (Park
Eq. 26), the Kalman or low-pass filter, the friction re-zero and the checks on every block
(:mod:`turning_force.core.estimation.settings` states them and holds the settings).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from turning_force.core import lti
from turning_force.core.compiled import (
    Arr,
    activate,
    compiled,
    entry,
    isclose,
    pairwise_sum,
    pymax,
    pymin,
)
from turning_force.core.estimation.settings import (
    IMPLAUSIBLE_RANGE_FACTOR,
    RESYNC_BLOCKS,
    EstimateStatus,
    EstimatorSettings,
    ForceEstimate,
)
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.plant.feeddrive import friction_current

__all__ = ['ForceEstimator', 'corrected_text', 'detail_text', 'estimator_correct',
           'estimator_update', 'rezeroed_scale', 'rezeroed_text']

FloatArray = npt.NDArray[np.float64]
OK, STALE, INVALID_INPUT, SATURATED = (int(s) for s in EstimateStatus)
_SQRT3 = math.sqrt(3.0)

# --- estimator parameters -------------------------------------------------------------------
E_KIND, E_FR_A, E_FR_B, E_FR_MIN, E_FR_MAX, E_MAP_OFF, E_MAP_PER, E_RANGE = range(8)
E_REZ_BELOW, E_REZ_AFTER, E_REZ_TAU, E_REZ_MAX, E_MAX_JUMP = range(8, 13)
E_GAIN_DT, E_K0, E_K1, E_NSEC, E_DB0, E_DB1, E_DA1 = range(13, 20)
E_SOS, E_SOS_ZI = 20, 44                      # 4 sections x 6, 4 sections x 2
E_REZ_FALL, E_REZ_TAIL, E_REZ_START = 52, 53, 54
E_SIZE = 55
KALMAN, LOWPASS = 0, 1
# estimator state
ES_ACTIVE, ES_DT, ES_LAST_T, ES_NEXT_T, ES_NRESYNC, ES_RESYNC = 0, 1, 2, 3, 4, 5   # 3 slots
ES_SCALE, ES_AIR, ES_RESTARTS = 8, 9, 10
ES_T, ES_F, ES_R, ES_IQ, ES_IFR, ES_STATUS = range(11, 17)
ES_DCODE, ES_DVAL = 17, 18                    # detail code, 2 values
ES_X = 20                                     # Kalman x (2) or low-pass zi (8) and dzi (1)
ES_LEVEL, ES_FALLEN = 29, 30                  # the force's level, the time fallen from it
ES_WINDOW, ES_STAGED = 31, 34                 # re-zero readings: q less offset, model, time
W_READ, W_MODEL, W_TIME = 0, 1, 2
ES_TAIL = 37                                  # the cut force's tail at the last sample [N]
ES_READ = 38                                  # the air move's readings taken so far [s]
ES_CUT = 39                                   # time over the lift in a row [s], to CUT_STAND_S
ES_CROSSED = 40                               # 1 once the estimate has been over rezero_below_n
# the scale before the move's last ROLLBACK_S to 2 ROLLBACK_S of readings, before its last
# snapshot, and the readings since that snapshot [s]
ES_SNAP = 41                                  # 3 slots
ES_FEED = 44                                  # the block's mean axis feed [mm/min]
ES_SIZE = 45
# The force's level the re-zero's fall is taken from: its mean over this time constant [s]. A
# fall below rezero_fall_fraction of it is air for as long as the level remembers the cut
# (about 2 s after an exit from a cut four times the estimate in air), long enough for the
# re-zero to bring the estimate in air below rezero_below_n, where it is air by the level alone.
LEVEL_TIME_CONSTANT_S = 2.0
# A program's approach in air ends where the estimate has stood over a friction drift's lift
# this long in a row [s]: a cut's force stays over it; the estimate's noise about a drift's
# 40-45 N in air (a sample's 19 N at 0.1 A of current noise, Kalman-filtered to some 4 N)
# crosses it for a block or two. The approach's readings wait as long for air after them:
# the contact's rise through the lift (87 N at a 30 % entry feed on the lathe's friction)
# takes tau_c ln((F_c - 40) / (F_c - 87)), 0.1 s at 163 N and tau_c 0.19 s, and is dropped.
CUT_STAND_S = 0.1
# An air move ends with a contact, whose force rises through rezero_below_n
# tau_c ln(F_c / (F_c - rezero_below_n)) after it, and the filter lags that by 10-20 ms: 70 ms
# at the 30 % entry feed's 148 N and tau_c 0.17 s, where REZERO_HOLD_S kept 20-40 ms of the
# rise out. The readings before that, weighted at 6 % each by the follow (0.02 s over
# rezero_time_constant_s), took the scale 1.6 % high on an unchanged machine (population seed
# 42 #1 with an approach in air: 1.08 -> 2.09 N steady, the sweep's best 1.11 -> 2.09 N). As
# the move ends, the scale goes back to what it was before its last ROLLBACK_S to
# 2 ROLLBACK_S of readings [s].
ROLLBACK_S = 0.05
# The re-zero's readings wait this long for air after them [s]: a re-entry's force passes
# rezero_below_n tau_c ln(F_c / (F_c - rezero_below_n)) after the contact (20 ms at the 30 %
# entry feed's 250 N and tau_c 0.19 s), and the force filter lags a rise some 10-20 ms more
# (the Kalman filter of 5 N noise: 30 N behind for 40 ms; the low-pass at 20 Hz: 11 ms of group
# delay). Longer holds cost short air moves their reading (bench_population seed 15, #49;
# bench_drift seed 16, #3: 1 s out of the work, 0.3 s of it re-zeroed).
REZERO_HOLD_S = 0.02
# Where the tail is still above this fraction of the force at the crossing as the re-zero
# starts, one estimate cannot tell tail from drift (the drift's noise is 1 / (1 - e) times the
# estimate's: 2x here).
TAIL_SEPARABLE = 0.5
# detail codes (ForceEstimator's one-line problems and notes)
D_NONE, D_LENGTHS, D_DT_BAD, D_DT_CHANGED, D_NONFINITE, D_STAMP_NONFINITE = range(6)
D_STAMP_NOT_AFTER, D_STAMP_JUMP, D_IMPLAUSIBLE, D_OVERFLOW, D_FILTER_OVERFLOW = range(6, 11)
D_SATURATED, D_REZEROED, D_CORRECTED = 11, 12, 13


# --- the estimator (core/estimation.py ForceEstimator.update) -------------------------------

@compiled
def _invalid(es: np.ndarray, code: int, a: float, b: float) -> int:
    if es[ES_ACTIVE] != 0.0:
        es[ES_ACTIVE] = 0.0
        es[ES_RESTARTS] += 1.0
    es[ES_STATUS] = INVALID_INPUT
    es[ES_DCODE], es[ES_DVAL], es[ES_DVAL + 1] = code, a, b
    return INVALID_INPUT


@compiled
def _stamp_problem(ep: np.ndarray, es: np.ndarray, t0: float, dt: float, n: int) -> int:
    """ForceEstimator._check_stamp: a detail code, or D_NONE (values in ES_DVAL)."""
    if not math.isfinite(t0):
        es[ES_DVAL] = t0
        return D_STAMP_NONFINITE
    last_t, next_t = es[ES_LAST_T], es[ES_NEXT_T]
    if last_t == -math.inf:
        return D_NONE
    if t0 <= last_t:
        problem = D_STAMP_NOT_AFTER
        es[ES_DVAL], es[ES_DVAL + 1] = t0, last_t
    elif t0 - next_t > ep[E_MAX_JUMP]:
        problem = D_STAMP_JUMP
        es[ES_DVAL], es[ES_DVAL + 1] = t0, t0 - next_t
    else:
        return D_NONE
    span = n * dt
    count = int(es[ES_NRESYNC])
    if not (count > 0 and abs(t0 - es[ES_RESYNC + count - 1] - span) <= 0.5 * dt):
        count = 0
    es[ES_RESYNC + count] = t0
    count += 1
    if count >= RESYNC_BLOCKS:   # a new time line: follow it
        es[ES_NRESYNC] = 0.0
        es[ES_LAST_T], es[ES_NEXT_T] = -math.inf, -math.inf
        es[ES_ACTIVE] = 0.0
        return D_NONE
    es[ES_NRESYNC] = count
    return problem


@compiled
def _tail_at_start(crossed_n: float, elapsed_s: float, force_n: float, tau_c_s: float) -> float:
    """The cut force's tail [N] as the re-zero starts, ``elapsed_s`` after the estimate fell
    through ``crossed_n``, where it reads ``force_n``: the force F decays as
    F_x exp(-t / tau_c) (Park Eq. 1) and the estimate reads F + delta (delta: the friction
    drift the re-zero is to read, constant in air). The crossing (F_x + delta = crossed_n) and
    the estimate now (F_x e + delta = force_n, e = exp(-elapsed_s / tau_c)) give both:
    delta = (force_n - crossed_n e) / (1 - e), the tail F_x e. A slow tau_c beside the wait
    (e near 1) cannot tell them apart: the tail is then taken as crossed_n e (no drift),
    never negative."""
    if not tau_c_s > 0.0:
        return 0.0
    e = math.exp(-elapsed_s / tau_c_s)
    delta = (force_n - crossed_n * e) / (1.0 - e) if e < TAIL_SEPARABLE else 0.0
    return pymax((crossed_n - delta) * e, 0.0)


@compiled
def _rezero(ep: np.ndarray, es: np.ndarray, force: float, dt: float, feed: np.ndarray,
            work: np.ndarray, mean_q: float) -> None:
    """ForceEstimator's friction re-zero, after the filter gave ``force`` for the block
    (``feed`` its feed rates, ``work[n:]`` scratch, ``mean_q`` its mean q current).

    Out of the material the q current less Eq. 26's offset is friction and the cut force's
    tail, nothing else. Park's Eq. 1 gives the tail: the force a depth no longer feeds decays
    as F(t) = F(t0) exp(-(t - t0) / tau_c). The estimate crossed rezero_below_n (or, where a
    friction drift holds it over that, the lift's top) the time counted in air ago, so the
    force was there then, and each block reads
    ``mean(i_q) - offset - c_F mean(F_cross exp(-t_air / tau_c))`` as friction (c_F: Eq.
    26's slope; tau_c: ``model_cutting_time_constant_s``). Where tau_c is slow beside
    rezero_after_s (0.19 s against 0.3 s: 8 N left as the re-zero starts, 40 N x
    exp(-0.3 / 0.19)) the tail was read as friction and the estimate sat some 3 N low in the
    next cut (bench_population seed 15, #49, #69; the false gain alarm of #73). Not the
    estimate, which a friction drift lifts too, anchors the tail: a drift delta that moved the
    crossing is off the tail by delta exp(-t_air / tau_c), under a fifth of it from
    rezero_after_s on at tau_c 0.19 s, and decaying.

    The re-entry is the mirror image: the force rises from the contact as
    F_c (1 - exp(-t / tau_c)) and the filter lags it; till the estimate passes rezero_below_n
    the re-zero would read the rise as friction (20-70 N in #49: the scale 4 % high, the
    estimate 7 N low in the cut). So readings are summed in windows of REZERO_HOLD_S, and a
    window is taken into the scale once another has followed it in air; where the estimate
    leaves the air the two open ones (one to two holds of readings) are dropped.

    Each air move measures the friction anew: the scale is the mean of the move's window
    readings (q less offset and tail over the calibrated friction, summed), each taken with
    the weight ``window / read`` (``read``: the move's windows taken so far, this one
    included), the least-squares estimate of a friction constant through the move. Where
    ``1 - exp(-window / rezero_time_constant_s)`` is larger (a long air move) the scale
    follows the readings with that time constant instead, and a friction that moves within
    the move is followed. An exponential follow alone went ``1 - exp(-air / tau)`` of the way
    in an air move: 74 % of a 44 % drift in the 0.4 s of reading a 1 s interruption left
    (bench_population seed 15, #131 and #157: the next cut 12 N low, read in full only at
    the move after). A session that starts in air has no tail to take off: nothing was cut
    (a tail from a crossing that never was, 40 N exp(-0.3 / tau_c), is 8.5 N at the re-zero's
    start on a chip of tau_c 0.19 s: read as friction 10 % low, population seed 42 #8 with an
    approach in air, 1.12 -> 1.98 N steady).

    A program approaches the work in air, at the entry feed, before its first cut. There no
    cut's level lies behind the estimate for it to have fallen from, and a friction drift
    beyond rezero_below_n (a 46 % drift of the lathe's friction at a 30 % entry feed: 44 N)
    held it out of the re-zero until the job's first exit, or for all of a job without one
    (bench_population seed 42, #27 and #43: 41 and 43 N under the reference throughout).
    With ``rezero_start_in_air`` (``identify`` writes it where the job's program starts in
    air) the estimate below the lift is air until it has stood over the lift for CUT_STAND_S
    (a cut), and no tail is taken off (none was cut); or until it has read air by the level
    alone (below rezero_below_n for rezero_after_s), after which the contact, and a light cut
    after it, are what they always were. A light cut at the session's start, inside the lift,
    is read as friction: the setting is for programs that approach the work in air.

    At a standstill (the axis slower than the curve's slowest feed) no chip is cut, and the
    estimate says nothing of a contact: the friction there is the static one, which the curve
    (measured from the air staircase's slowest level up) does not hold. An underdamped servo
    told the entry feed after 150 % as the tool leaves rings down through the standstill, and
    the estimate swung to 45 N there (population seed 15 #99, 18 rad/s damped at 0.5 and
    drifted x1.28 slower, a curve measured from 10.5 mm/min). Taken for a contact, it restarted
    the count of air, and the re-zero took off the tail of a cut 0.3 s gone instead of 1 s:
    the scale 3-5 % low, the next cuts' estimate 4-7 N high (5.0 N steady against 1.2 N).
    There the counts of air, of the fall and of the cut hold."""
    n = feed.size
    below, after = ep[E_REZ_BELOW], ep[E_REZ_AFTER]
    fa, fb, fmin, fmax = ep[E_FR_A], ep[E_FR_B], ep[E_FR_MIN], ep[E_FR_MAX]
    per = ep[E_MAP_PER]
    slowest = abs(feed[0])
    for i in range(1, n):
        slowest = min(slowest, abs(feed[i]))
    in_air = below > 0 and abs(force) < below
    # a swing out of the air band at a standstill is no contact (see the docstring)
    still = below > 0 and not in_air and slowest < fmin
    if not still:
        es[ES_AIR] = es[ES_AIR] + n * dt if in_air else 0.0
    if not (in_air or still):
        es[ES_CROSSED] = 1.0
    # A friction drift lifts the estimate in air by up to rezero_max_change of the friction:
    # the time the estimate has sat in that lift, fallen from the cut's level, counts as air
    # too (paused where it dips below rezero_below_n, where ES_AIR counts; reset where the
    # force rises out of it: a cut). An exit from the cut without a drift passes the lift in
    # less than a tau_c and waits below rezero_below_n, as it always did.
    lifted = below + ep[E_REZ_MAX] * abs(friction_current(fa, fb, fmin, fmax, feed[n - 1])) / per
    # rezero_start_in_air: until the estimate has stood over the lift (a cut, not its noise)
    # or below rezero_below_n for rezero_after_s (no drift the level alone misses), the
    # program's approach, all of it below the lift air (an estimate about rezero_below_n,
    # split between the two counts, reached neither: seed 15 #28's 39 %)
    if es[ES_CUT] < CUT_STAND_S and not still:
        es[ES_CUT] = (CUT_STAND_S if es[ES_AIR] >= after else
                      es[ES_CUT] + n * dt if force >= lifted else 0.0)
    approach = ep[E_REZ_START] != 0.0 and es[ES_CUT] < CUT_STAND_S
    fallen = force < ep[E_REZ_FALL] * es[ES_LEVEL]
    if below > 0 and force < lifted and (approach or (not in_air and fallen)):
        es[ES_FALLEN] += n * dt
    elif not (in_air or still):
        es[ES_FALLEN] = 0.0
    es[ES_LEVEL] += (force - es[ES_LEVEL]) * (1.0 - math.exp(-n * dt / LEVEL_TIME_CONSTANT_S))
    if not (es[ES_AIR] >= after or es[ES_FALLEN] >= after):
        if es[ES_READ] > 0.0:   # the move's end: its last readings held the contact's rise
            es[ES_SCALE] = es[ES_SNAP]
            es[ES_DCODE], es[ES_DVAL] = D_REZEROED, es[ES_SCALE]
        for k in range(6):   # readings not followed by a window of air: the cut's rise
            es[ES_WINDOW + k] = 0.0
        es[ES_TAIL] = math.nan
        es[ES_READ] = 0.0
        return
    tau_c = ep[E_REZ_TAIL]
    decay = math.exp(-dt / tau_c) if tau_c > 0.0 else 0.0
    if math.isnan(es[ES_TAIL]):   # the re-zero starts
        es[ES_SNAP], es[ES_SNAP + 1], es[ES_SNAP + 2] = es[ES_SCALE], es[ES_SCALE], 0.0
    if math.isnan(es[ES_TAIL]) and (approach or es[ES_CROSSED] == 0.0):   # no cut yet: no tail
        es[ES_TAIL] = 0.0
    elif math.isnan(es[ES_TAIL]):   # where the tail is
        es[ES_TAIL] = _tail_at_start(below if es[ES_AIR] >= after else lifted,
                                     es[ES_AIR] if es[ES_AIR] >= after else es[ES_FALLEN],
                                     force, tau_c) / decay ** n if decay > 0.0 else 0.0
    tail, tail_sum = es[ES_TAIL], 0.0
    for _ in range(n):
        tail *= decay
        tail_sum += tail
    es[ES_TAIL] = tail
    if slowest < fmin:
        return
    # Friction opposes the motion: read along it. Every feed of the block is at least fmin
    # from standstill, so one sign holds for all; a window summed across a reversal (an
    # underdamped servo ringing through zero after the override drops at an exit) summed
    # readings of both signs, whose model came near zero: the ratio threw the scale to its
    # bound (population seed 42 #14 at a 20 % entry feed, 0.994 -> 0.500 in one window; the
    # next cuts 45 N high).
    sign = 1.0 if feed[0] > 0.0 else -1.0
    for i in range(n):
        work[n + i] = sign * friction_current(fa, fb, fmin, fmax, feed[i])
    model = pairwise_sum(work, n, n)
    if abs(model) < 1e-9 * n:
        return
    # the cut force's tail pushes the same way whichever way the axis runs (Eq. 26: the q
    # current's share of it is c_F F); the friction turns with the motion
    es[ES_WINDOW + W_READ] += sign * (n * (mean_q - ep[E_MAP_OFF]) - per * tail_sum)
    es[ES_WINDOW + W_MODEL] += model
    es[ES_WINDOW + W_TIME] += n * dt
    # in the approach a cut's contact rises through the lift before it ends it: its readings
    # wait as long for air after them
    if es[ES_WINDOW + W_TIME] >= (CUT_STAND_S if approach else REZERO_HOLD_S):
        if es[ES_STAGED + W_TIME] > 0.0:   # a window of air followed it: read
            scale = es[ES_SCALE]
            window = es[ES_STAGED + W_TIME]
            es[ES_READ] += window
            es[ES_SNAP + 2] += window
            if es[ES_SNAP + 2] >= ROLLBACK_S:
                es[ES_SNAP], es[ES_SNAP + 1], es[ES_SNAP + 2] = es[ES_SNAP + 1], scale, 0.0
            # the air move's mean so far, or the exponential follow where that is faster
            weight = pymax(window / es[ES_READ], 1.0 - math.exp(-window / ep[E_REZ_TAU]))
            ratio = es[ES_STAGED + W_READ] / es[ES_STAGED + W_MODEL]
            new_scale = scale + weight * (ratio - scale)
            limit = ep[E_REZ_MAX]
            es[ES_SCALE] = pymin(pymax(new_scale, 1.0 - limit), 1.0 + limit)
        for k in range(3):
            es[ES_STAGED + k] = es[ES_WINDOW + k]
            es[ES_WINDOW + k] = 0.0
    es[ES_DCODE], es[ES_DVAL] = D_REZEROED, es[ES_SCALE]


@compiled
def estimator_update(ep: np.ndarray, es: np.ndarray, t0: float, dt: float, u: np.ndarray,
                     v: np.ndarray, angle: np.ndarray, feed: np.ndarray,
                     work: np.ndarray) -> int:
    """One block; the estimate in es[ES_T:ES_STATUS + 1], its detail in ES_DCODE; returns the
    status. ``work`` holds 2 n scratch values (i_q, then the force). The caller has set the
    filter's coefficients for ``dt`` (E_GAIN_DT) where a new filter may start."""
    es[ES_DCODE] = D_NONE
    es[ES_FEED] = math.nan
    n = u.size
    if n == 0 or v.size != n or angle.size != n or feed.size != n:
        return _invalid(es, D_LENGTHS, 0.0, 0.0)
    if not (math.isfinite(dt) and dt > 0):
        return _invalid(es, D_DT_BAD, dt, 0.0)
    if es[ES_ACTIVE] != 0.0 and not isclose(dt, es[ES_DT], 1e-6):
        return _invalid(es, D_DT_CHANGED, es[ES_DT], dt)
    bad = 0
    for i in range(n):
        bad += (not math.isfinite(u[i])) + (not math.isfinite(v[i])) \
            + (not math.isfinite(angle[i])) + (not math.isfinite(feed[i]))
    if bad:
        return _invalid(es, D_NONFINITE, float(bad), 0.0)
    problem = _stamp_problem(ep, es, t0, dt, n)
    if problem != D_NONE:
        return _invalid(es, problem, es[ES_DVAL], es[ES_DVAL + 1])
    peak_u, peak_v = abs(u[0]), abs(v[0])
    for i in range(1, n):
        peak_u = max(peak_u, abs(u[i]))
        peak_v = max(peak_v, abs(v[i]))
    peak = pymax(peak_u, peak_v)
    if peak > IMPLAUSIBLE_RANGE_FACTOR * ep[E_RANGE]:
        return _invalid(es, D_IMPLAUSIBLE, peak, 0.0)
    scale = es[ES_SCALE]
    fa, fb, fmin, fmax = ep[E_FR_A], ep[E_FR_B], ep[E_FR_MIN], ep[E_FR_MAX]
    offset, per = ep[E_MAP_OFF], ep[E_MAP_PER]
    friction = 0.0
    finite = True
    for i in range(n):
        i_beta = (u[i] + 2.0 * v[i]) / _SQRT3
        cos, sin = math.cos(angle[i]), math.sin(angle[i])
        current_q = -u[i] * sin + i_beta * cos
        friction = scale * friction_current(fa, fb, fmin, fmax, feed[i])
        raw = (current_q - friction - offset) / per
        work[i] = current_q
        work[n + i] = raw
        finite = finite and math.isfinite(raw)
    if not finite:
        return _invalid(es, D_OVERFLOW, peak, 0.0)
    if es[ES_ACTIVE] == 0.0:
        es[ES_DT] = dt
        es[ES_ACTIVE] = 1.0
        first = work[n]
        if ep[E_KIND] == KALMAN:
            es[ES_X], es[ES_X + 1] = first, 0.0
        else:
            for s in range(int(ep[E_NSEC])):
                es[ES_X + 2 * s] = ep[E_SOS_ZI + 2 * s] * first
                es[ES_X + 2 * s + 1] = ep[E_SOS_ZI + 2 * s + 1] * first
            es[ES_X + 8] = ep[E_DB1] * first
    force = 0.0
    rate = 0.0
    if ep[E_KIND] == KALMAN:
        fdt, k0, k1 = es[ES_DT], ep[E_K0], ep[E_K1]
        x0, x1 = es[ES_X], es[ES_X + 1]
        for i in range(n):
            x0 = x0 + fdt * x1
            innovation = work[n + i] - x0
            x0, x1 = x0 + k0 * innovation, x1 + k1 * innovation
        es[ES_X], es[ES_X + 1] = x0, x1
        force, rate = x0, x1
    else:
        sections = int(ep[E_NSEC])
        db0, db1, da1 = ep[E_DB0], ep[E_DB1], ep[E_DA1]
        for i in range(n):
            x = work[n + i]
            for s in range(sections):
                base = E_SOS + 6 * s
                z = ES_X + 2 * s
                x_new = ep[base] * x + es[z]
                es[z] = ep[base + 1] * x - ep[base + 4] * x_new + es[z + 1]
                es[z + 1] = ep[base + 2] * x - ep[base + 5] * x_new
                x = x_new
            y = es[ES_X + 8] + db0 * x
            es[ES_X + 8] = db1 * x - da1 * y
            force, rate = x, y
    if not (math.isfinite(force) and math.isfinite(rate)):
        return _invalid(es, D_FILTER_OVERFLOW, peak, 0.0)
    es[ES_LAST_T] = t0
    es[ES_NEXT_T] = t0 + n * dt
    es[ES_NRESYNC] = 0.0
    mean_q = pairwise_sum(work, 0, n) / n
    _rezero(ep, es, force, dt, feed, work, mean_q)
    status = OK
    if peak > ep[E_RANGE]:
        status = SATURATED
        es[ES_DCODE], es[ES_DVAL] = D_SATURATED, peak
    es[ES_T] = t0 + (n - 1) * dt
    es[ES_F], es[ES_R], es[ES_IQ] = force, rate, mean_q
    es[ES_IFR], es[ES_STATUS] = friction, status
    es[ES_FEED] = pairwise_sum(feed, 0, n) / n
    return status


@compiled
def estimator_correct(ep: np.ndarray, es: np.ndarray, offset_n: float) -> None:
    """The drift monitor read a friction drift in the cut (:func:`.drift.drift_correction`):
    ``offset_n`` [N] more friction than the estimator subtracts. The friction scale takes it
    at the last block's feed (Park Eq. 25 scaled, within ``rezero_max_change``, as the re-zero
    in air), and the filter's state and the force's level move by what the scale took, as if
    the filter had seen the corrected force all along (it is linear: a constant input's
    steady state superposes): the next block's estimate steps, without a transient of the
    filter's own. The detail says so (D_CORRECTED: the new scale, the force taken off)."""
    scale = es[ES_SCALE]
    per = ep[E_MAP_PER]
    calibrated = es[ES_IFR] / scale if scale != 0.0 else 0.0
    if not (math.isfinite(offset_n) and calibrated > 0.0 and per > 0.0):
        return
    limit = ep[E_REZ_MAX]
    new_scale = pymin(pymax(scale + offset_n * per / calibrated, 1.0 - limit), 1.0 + limit)
    taken = (new_scale - scale) * calibrated / per
    es[ES_SCALE] = new_scale
    es[ES_LEVEL] -= taken
    if ep[E_KIND] == KALMAN:
        es[ES_X] -= taken
    else:
        for s in range(int(ep[E_NSEC])):
            es[ES_X + 2 * s] -= ep[E_SOS_ZI + 2 * s] * taken
            es[ES_X + 2 * s + 1] -= ep[E_SOS_ZI + 2 * s + 1] * taken
        es[ES_X + 8] -= ep[E_DB1] * taken
    es[ES_DCODE], es[ES_DVAL], es[ES_DVAL + 1] = D_CORRECTED, new_scale, taken


@entry('void(float64[::1], float64[::1], float64)')
def estimate_correct(ep: Arr, es: Arr, offset_n: float) -> None:
    """:func:`estimator_correct` from Python (the estimator node, the per-block chain)."""
    estimator_correct(ep, es, offset_n)


@entry('int64(float64[::1], float64[::1], float64, float64, float64[::1], float64[::1], '
      'float64[::1], float64[::1], float64[::1])')
def estimate_block(ep: Arr, es: Arr, t0: float, dt: float, u: Arr, v: Arr, angle: Arr,
                   feed: Arr, work: Arr) -> int:
    """:func:`estimator_update` for one block from Python (the nodes, replay)."""
    return estimator_update(ep, es, t0, dt, u, v, angle, feed, work)



class ForceEstimator:
    """Force and force rate from blocks of feed-drive currents.

    A block with non-finite samples, mismatched arrays, a bad or changed sample period, or a
    stamp not after the previous one (or further ahead than ``max_stamp_jump_s``) is reported
    ``INVALID_INPUT``; so is a block with a sample past twice the sensor range (no Hall sensor
    reads that: a corrupt value) or whose values overflow the filter.
    The estimate then repeats the last good force, always finite, and the filter restarts at
    the next good block: a gap in the data is not bridged by a filter state that no longer
    matches it.

    Stamps: a DAQ that restarts (or a clock that steps) starts a new time line; after
    ``RESYNC_BLOCKS`` contiguous blocks on it, the estimator follows it. One stray stamp
    (1e9 s) is refused and the blocks after it, on the old time line, are taken as before.

    Friction re-zero: while the tool is out of the material (Park Eq. 25 drifts with the
    slideway's temperature and lubrication), the q current less Eq. 26's zero-force offset is
    friction alone, and its ratio to the calibrated curve at this feed scales the curve, within
    ``rezero_max_change``. Out of the material is an estimate below ``rezero_below_n`` for
    ``rezero_after_s``; or, as long: within the lift a friction drift gives the estimate in
    air (``rezero_max_change`` of the friction at this feed above ``rezero_below_n``) and below
    ``rezero_fall_fraction`` of the force's level over the last seconds
    (LEVEL_TIME_CONSTANT_S): the tool has left a cut, and a drifted friction holds the
    estimate up. A light cut is not a fall (Park's Fig. 13 cuts at 50 N throughout). The tail
    of the force the tool left, decaying with ``model_cutting_time_constant_s``, is taken off
    what the re-zero reads, and the readings a re-entry's rise reached are dropped
    (:func:`_rezero`).

    The arithmetic is written once, as the compiled ``estimator_update`` of
    :mod:`turning_force.core.kernel.loops` (which the compiled loops run on :meth:`arrays_for`);
    this class holds its parameters and state and puts its codes into words.
    """

    def __init__(self, settings: EstimatorSettings) -> None:
        activate()   # compiled, not interpreted, from the first block
        self.settings = settings
        self._params = _estimator_params(settings)
        state = np.zeros(ES_SIZE)
        state[ES_LAST_T] = state[ES_NEXT_T] = -math.inf
        state[ES_SCALE] = 1.0
        state[ES_TAIL] = math.nan
        state[ES_STATUS] = EstimateStatus.STALE
        self._state = state
        self._work = np.empty(0)
        self._last = ForceEstimate(0.0, 0.0, 0.0, 0.0, 0.0, EstimateStatus.STALE, 'no data yet')

    @property
    def last(self) -> ForceEstimate:
        return self._last

    @property
    def friction_scale(self) -> float:
        """Re-zeroed friction / calibrated friction."""
        return float(self._state[ES_SCALE])

    def correct(self, offset_n: float) -> str:
        """The drift monitor's friction reading in the cut (:func:`estimator_correct`), taken
        from the next block on: the line that says what it did ('' where it did nothing)."""
        state = self._state
        state[ES_DCODE] = D_NONE
        estimate_correct(self._params, state, float(offset_n))
        if state[ES_DCODE] != D_CORRECTED:
            return ''
        return corrected_text(float(state[ES_DVAL]), float(state[ES_DVAL + 1]))

    @property
    def restarts(self) -> int:
        """How often the filter restarted after a refused block."""
        return int(self._state[ES_RESTARTS])

    def arrays_for(self, sample_period_s: float) -> tuple[FloatArray, FloatArray]:
        """(parameters, state) as ``estimator_update`` reads them (live: a loop that runs
        them runs this estimator), the filter's coefficients set for blocks sampled at
        ``sample_period_s`` (where that is one)."""
        if (self._state[ES_ACTIVE] == 0.0 and math.isfinite(sample_period_s)
                and sample_period_s > 0):
            _set_filter(self._params, self.settings, sample_period_s)
        return self._params, self._state

    def update(self, block: CurrentBlock) -> ForceEstimate:
        """Process one block; return the estimate at its last sample."""
        params, state = self.arrays_for(block.sample_period_s)
        n = len(block)
        if self._work.size < 2 * n:
            self._work = np.empty(2 * n)
        status = int(estimate_block(
            params, state, float(block.t0_s), float(block.sample_period_s),
            _contiguous(block.phase_u_a), _contiguous(block.phase_v_a),
            _contiguous(block.rotor_angle_rad), _contiguous(block.feed_rate_mm_min),
            self._work))
        detail = detail_text(self.settings, block, int(state[ES_DCODE]),
                             float(state[ES_DVAL]), float(state[ES_DVAL + 1]))
        if status == EstimateStatus.INVALID_INPUT:
            last = self._last
            self._last = ForceEstimate(last.t_s, last.force_n, last.force_rate_n_s,
                                       last.current_q_a, last.friction_current_a,
                                       EstimateStatus.INVALID_INPUT, detail)
        else:
            self._last = ForceEstimate(
                float(state[ES_T]), float(state[ES_F]), float(state[ES_R]),
                float(state[ES_IQ]), float(state[ES_IFR]), EstimateStatus(status),
                detail, float(state[ES_FEED]))
        return self._last


def _contiguous(values: FloatArray) -> FloatArray:
    """What the compiled function takes: C-contiguous, writable float64 (a block decoded from
    a bag is a read-only view of the message's buffer)."""
    out = np.ascontiguousarray(values, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


def _estimator_params(settings: EstimatorSettings) -> FloatArray:
    """The estimator's parameters (``E_*``); the filter's coefficients come with
    :func:`_set_filter` once the sample period is known."""
    p = np.zeros(E_SIZE)
    p[E_KIND] = KALMAN if settings.force_filter == 'kalman' else LOWPASS
    f, m = settings.friction, settings.current_map
    p[E_FR_A], p[E_FR_B] = f.a_a_per_mm_min2, f.b_a
    p[E_FR_MIN], p[E_FR_MAX] = f.min_feed_mm_min, f.max_feed_mm_min
    p[E_MAP_OFF], p[E_MAP_PER] = m.offset_a, m.per_force_a_n
    p[E_RANGE] = settings.current_range_a
    p[E_REZ_BELOW], p[E_REZ_AFTER] = settings.rezero_below_n, settings.rezero_after_s
    p[E_REZ_TAU] = settings.rezero_time_constant_s
    p[E_REZ_MAX] = settings.rezero_max_change
    p[E_REZ_FALL] = settings.rezero_fall_fraction
    p[E_REZ_TAIL] = settings.model_cutting_time_constant_s
    p[E_REZ_START] = float(settings.rezero_start_in_air)
    p[E_MAX_JUMP] = settings.max_stamp_jump_s
    p[E_GAIN_DT] = math.nan
    return p


def _set_filter(params: FloatArray, settings: EstimatorSettings,
                dt_s: float) -> None:
    """The filter's coefficients for sample period ``dt_s``.

    - ``kalman``: the steady-state gain of a Kalman filter for x = [F, dF/dt] under white
      force acceleration (El-Sinawi 2011, Sec. 4, on the force alone; :func:`lti.kalman_gain`):
      the filter is then linear and time-invariant.
    - ``lowpass``: Park's Butterworth preprocessor as second-order sections (cut-off at most
      0.9 x Nyquist), its unit initial state, and the filtered derivative
      ``y[k] = alpha y[k-1] + (1 - alpha) (x[k] - x[k-1]) / dt``,
      ``alpha = exp(-dt / derivative_time_constant_s)``.
    """
    if params[E_GAIN_DT] == dt_s:
        return
    if settings.force_filter == 'kalman':
        params[E_K0], params[E_K1] = lti.kalman_gain(
            dt_s, settings.kalman_accel_noise_n_s2, settings.kalman_force_noise_n)
    else:
        from scipy import signal  # 0.7-0.9 s to import: only where the low-pass is chosen

        cutoff = min(settings.lowpass_cutoff_hz, 0.9 * 0.5 / dt_s)
        sos = signal.butter(settings.lowpass_order, cutoff, fs=1.0 / dt_s, output='sos')
        if sos.shape[0] > 4:
            raise ValueError(f'lowpass_order {settings.lowpass_order}: more than 4 sections')
        params[E_NSEC] = sos.shape[0]
        params[E_SOS:E_SOS + sos.size] = sos.ravel()
        zi = signal.sosfilt_zi(sos) * 1.0
        params[E_SOS_ZI:E_SOS_ZI + zi.size] = zi.ravel()
        alpha = math.exp(-dt_s / settings.derivative_time_constant_s)
        params[E_DB0], params[E_DB1] = np.array([1.0, -1.0]) * (1.0 - alpha) / dt_s
        params[E_DA1] = -alpha
    params[E_GAIN_DT] = dt_s


def detail_text(settings: EstimatorSettings, block: CurrentBlock, code: int, a: float,
                b: float) -> str:
    """The one line (:attr:`ForceEstimate.detail`) for the estimator's detail code and values
    on ``block``."""
    if code == D_NONE:
        return ''
    if code == D_LENGTHS:
        arrays = (block.phase_u_a, block.phase_v_a, block.rotor_angle_rad,
                  block.feed_rate_mm_min)
        return f'array lengths {[x.size for x in arrays]} differ or are empty'
    if code == D_DT_BAD:
        return f'sample period {block.sample_period_s!r} s is not a positive number'
    if code == D_DT_CHANGED:
        return f'sample period changed from {a!r} s to {block.sample_period_s!r} s'
    if code == D_NONFINITE:
        return f'{int(a)} non-finite samples'
    if code == D_STAMP_NONFINITE:
        return f'stamp {block.t0_s!r} s is not finite'
    if code == D_STAMP_NOT_AFTER:
        return f'stamp {block.t0_s!r} s is not after the previous {b!r} s'
    if code == D_STAMP_JUMP:
        return (f'stamp {block.t0_s!r} s jumps {b:.6g} s past the previous block '
                f'(max_stamp_jump_s {settings.max_stamp_jump_s:g})')
    if code == D_IMPLAUSIBLE:
        return (f'phase current {a:.3g} A is beyond {IMPLAUSIBLE_RANGE_FACTOR:g} x the '
                f'sensor range ({settings.current_range_a:g} A): not a reading')
    if code == D_OVERFLOW:
        return f'currents overflow the force computation (|i| up to {a:.3g} A)'
    if code == D_FILTER_OVERFLOW:
        return f'force filter overflowed (|i| up to {a:.3g} A)'
    if code == D_SATURATED:
        return f'phase current {a:.3g} A beyond the sensor range'
    if code == D_CORRECTED:
        return corrected_text(a, b)
    return rezeroed_text(a)


REZEROED_TEXT = 'friction re-zeroed in air: '
REZEROED_UNIT = ' x calibrated'


def rezeroed_text(scale: float) -> str:
    """The line for a friction re-zero to ``scale``."""
    return f'{REZEROED_TEXT}{scale:.3f}{REZEROED_UNIT}'


def corrected_text(scale: float, taken_n: float) -> str:
    """The line for the drift monitor's friction correction in the cut to ``scale``, the
    estimate ``taken_n`` [N] lower."""
    return (f'friction corrected in the cut by the drift monitor: {scale:.3f}{REZEROED_UNIT} '
            f'(estimate {-taken_n:+.1f} N); an air move re-zeroes it')


def rezeroed_scale(detail: str) -> float | None:
    """The scale a re-zero's line (:func:`rezeroed_text`) says, None where the line is not
    one (what a node that has the estimate's message, not the estimator, reads)."""
    if not (detail.startswith(REZEROED_TEXT) and detail.endswith(REZEROED_UNIT)):
        return None
    try:
        return float(detail[len(REZEROED_TEXT):-len(REZEROED_UNIT)])
    except ValueError:
        return None


