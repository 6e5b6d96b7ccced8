"""The drift monitor: while cutting, the force the estimator reports is compared with what the
identified machine model (``turning-force identify``: dead time, servo, cutting exponent and
tau_c, K_s d, friction, with their uncertainties) predicts from the override the PMC applied;
when the machine no longer matches it, the monitor says what drifted and by how much.

The model runs as a bank (:data:`DEAD_OFFSETS`, :data:`SERVO_POWERS`): the identified one, the
same with the PMC dead time a whole number of control periods longer or shorter, and with the
servo slower or faster by powers of :data:`SERVO_RATIO`. Each member's output ``y`` is the
force the identified process gives at a gain of one, ``y = lag_tau_c((v / v_prog)^g)`` (Park
Eq. 1 with Kienzle's exponent, Hwang & Chen Eq. 3), of the feed ``v`` its servo delivers
(Park Eq. 2 or Hwang & Chen Eq. 1, zero-order hold at the control period). Over an
exponentially weighted window of ``drift_memory_s`` in the cut (from the time the model's
entry transient has died away), each member's force is fitted as ``F = K y + c`` by least
squares. Three tests follow, each a likelihood ratio on the residual's sum of squares, its
effective sample count taken from the residual's lag-one autocorrelation ``rho`` (Bartlett:
``n_eff = n (1 - rho) / (1 + rho)``), against ``drift_sigmas`` squared (chi-square, one degree
of freedom; Basseville & Nikiforov, Detection of Abrupt Changes, 1993, Sec. 4.2 and 7.2):

- the lag: the best member of the bank against the identified one (PMC dead time or servo);
- the level, on the member that fits best: the gain ``F = K y`` against the identified
  ``F = K_id y`` (process gain, ``K / K_id``), or an offset ``F = K_id y + c`` (the feed-drive
  friction the estimator subtracts: ``c`` over the identified friction's share of the force);
  where the job's depths span a range of K_s d, ``K_id`` is the nearest end of that range.

Members within ``drift_sigmas`` standard deviations of the identified value, and gains or
offsets within that many of the identified process model's own error (its residual in the
commissioning cut and its parameters' standard deviations), are not drift; nor is an offset
larger than the friction change the estimator's re-zero would follow
(``drift_friction_max_change``, its ``rezero_max_change``). Where the window cannot tell a gain
from an offset (a cut at one depth and feed shows a level more than its cause), the alarm
names the one that fits better and the other beside it. A cause raises the
alarm once it has stood for ``drift_memory_s``; the alarm holds (a drift is the machine's, not
the cut's) until another cause is found.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core import lti
from turning_force.core.compiled import compiled, pymax, pymin

if TYPE_CHECKING:
    from turning_force.core.control.law import ControllerBase
    from turning_force.core.experiment import Experiment
    from turning_force.core.identify import Identification

__all__ = ['CAUSES', 'PARAMS', 'STATE', 'alarm', 'drift_applied', 'drift_fill', 'drift_step',
           'drift_text', 'identified']

FloatArray = npt.NDArray[np.float64]

# The bank: dead time offsets [control periods] and servo time scales SERVO_RATIO^k.
DEAD_OFFSETS = (-4, -3, -2, -1, 1, 2, 3, 4, 5, 6, 7, 8)
SERVO_RATIO = 1.2
SERVO_POWERS = (-3, -2, -1, 1, 2, 3, 4, 5)
N_MODELS = 1 + len(DEAD_OFFSETS) + len(SERVO_POWERS)
# What drifted (the alarm's code, the trace's ``drift_alarm``).
NONE, DEAD_TIME, SERVO, GAIN, FRICTION = range(5)
CAUSES = ('', 'PMC dead time', 'servo', 'process gain', 'friction')
HISTORY = 64   # control periods of applied override kept (the longest delay in the bank)

# --- parameters (dp) ---------------------------------------------------------------------------
(D_ON, D_PERIOD, D_FORGET, D_SIGMAS, D_POLE, D_EXPONENT, D_SETTLE, D_MEMORY, D_K_LO, D_K_HI,
 D_K_STD, D_FRICTION, D_FRICTION_STD, D_FRICTION_MAX, D_DEAD, D_DEAD_STD, D_SERVO_STD) = range(17)
D_MODELS = 17
# per member: delay [periods], servo b0 b1 b2 a1 a2 (direct form II transposed), cause, size
M_DELAY, M_B0, M_B1, M_B2, M_A1, M_A2, M_CAUSE, M_SIZE = range(8)
M_FIELDS = 8
PARAMS = D_MODELS + N_MODELS * M_FIELDS

# --- state (ds) --------------------------------------------------------------------------------
# the override applied to the coming block (NaN: none told yet), the ring's index, whether the
# bank runs, the time in the cut, the window's sums (weights, F, F^2), the cause standing and
# since when, the alarm (its cause, size, standard deviation), how often it was raised, and
# where the cut cannot tell a gain from a friction drift, the other one's reading.
(DS_APPLIED, DS_AT, DS_STARTED, DS_IN_CUT, DS_S1, DS_SF, DS_SFF, DS_CAUSE, DS_SIZE,
 DS_SINCE, DS_ALARM, DS_ALARM_SIZE, DS_ALARM_STD, DS_ALARMS, DS_ALARM_ALT) = range(15)
DS_HIST = 15
DS_MODELS = DS_HIST + HISTORY
# per member: servo state z0 z1, output y, sums y, y^2, y F, and of its residual: squared,
# times the one before, the one before
Z0, Z1, Y, SY, SYY, SYF, SRR, SR1, RPREV = range(9)
S_FIELDS = 9
STATE = DS_MODELS + N_MODELS * S_FIELDS


def identified(ident: Identification, job: Experiment, depths_mm: tuple[float, float],
               cut_depth_mm: float) -> dict[str, float | bool]:
    """The ``force_controller`` settings that turn the monitor on for a job cutting
    ``depths_mm`` deep on the machine ``ident`` identified from a cut ``cut_depth_mm`` deep
    (what ``identify`` writes beside the model): K_s d over the job's depths, and the standard
    deviation of each identified value. A force the process model predicts is as uncertain as
    its parameters and as its residual in the commissioning cut (the model error the fit
    left, relative to the job's reference force)."""
    ksd = ident.ksd_n_mm
    residual = ident.process.residual_rms / job.controller.reference_force_n
    feed_rate = job.controller.programmed_feed_rate_mm_min
    friction_a = float(ident.friction_model.current_a(np.array([feed_rate]))[0])
    friction = ident.friction
    friction_std = max(friction[k].relative_std() for k in ('at_min_feed_a', 'at_max_feed_a'))
    servo = ident.servo
    scale = servo['time_constant_s' if servo.model == 'first_order' else 'natural_freq_rad_s']
    return {
        'drift_monitor': True,
        'drift_ksd_min_n_mm': ksd.value * depths_mm[0] / cut_depth_mm,
        'drift_ksd_max_n_mm': ksd.value * depths_mm[1] / cut_depth_mm,
        'drift_ksd_std': math.hypot(ksd.relative_std(), residual),
        'drift_friction_n': abs(friction_a) / job.estimator.current_map.per_force_a_n,
        'drift_friction_std': min(friction_std, 1.0),
        'drift_friction_max_change': job.estimator.rezero_max_change,
        'drift_dead_time_std_s': min(ident.dead_time_s.std, 1.0),
        'drift_servo_std': min(scale.relative_std(), 1.0),
    }


def drift_fill(c: ControllerBase) -> FloatArray:
    """The monitor's parameters from the controller's settings: the identified model
    (``model_*``) and the monitor's (``drift_*``); all zero (off) where ``drift_monitor`` is."""
    p = np.zeros(PARAMS)
    if not c.drift_monitor:
        return p
    h = c.control_period_s
    p[D_ON], p[D_PERIOD], p[D_SIGMAS] = 1.0, h, c.drift_sigmas
    p[D_FORGET] = math.exp(-h / c.drift_memory_s)
    p[D_MEMORY] = c.drift_memory_s
    p[D_POLE] = math.exp(-h / c.model_cutting_time_constant_s)
    p[D_EXPONENT] = c.model_cutting_exponent
    second = c.model_servo_model == 'second_order'
    # an entry (a depth step) reaches the force through the process lag alone (the bank has
    # followed the feed through dead time and servo all along): five tau_c, and it is in y
    p[D_SETTLE] = 5.0 * c.model_cutting_time_constant_s
    # the force at the programmed feed (y = 1) over the job's K_s d range
    feed = c.programmed_feed_mm_rev
    p[D_K_LO], p[D_K_HI] = c.drift_ksd_min_n_mm * feed, c.drift_ksd_max_n_mm * feed
    p[D_K_STD] = c.drift_ksd_std
    p[D_FRICTION], p[D_FRICTION_STD] = c.drift_friction_n, c.drift_friction_std
    p[D_FRICTION_MAX] = c.drift_friction_max_change
    p[D_DEAD], p[D_DEAD_STD] = c.model_dead_time_s, c.drift_dead_time_std_s
    p[D_SERVO_STD] = c.drift_servo_std
    members = [(0.0, 1.0, NONE, 0.0)]
    members += [(j * h, 1.0, DEAD_TIME, j * h) for j in DEAD_OFFSETS]
    members += [(0.0, SERVO_RATIO ** k, SERVO, SERVO_RATIO ** k) for k in SERVO_POWERS]
    for m, (extra_s, scale, cause, size) in enumerate(members):
        row = D_MODELS + m * M_FIELDS
        delay = c.model_dead_time_s + extra_s
        p[row + M_DELAY] = delay / h if delay >= 0.0 else -1.0   # -1: not in the bank
        if second:
            wn = c.model_servo_natural_freq_rad_s / scale
            b, a = lti.zoh([wn * wn], [1.0, 2.0 * c.model_servo_damping * wn, wn * wn], h)
            p[row + M_B0:row + M_B0 + 3], p[row + M_A1:row + M_A1 + 2] = b, a[1:]
        else:
            b, a = lti.zoh([1.0], [c.model_servo_time_constant_s * scale, 1.0], h)
            p[row + M_B0:row + M_B0 + 2], p[row + M_A1] = b, a[1]
        p[row + M_CAUSE], p[row + M_SIZE] = cause, size
    return p


@compiled
def drift_applied(ds: np.ndarray, applied_pct: float) -> None:
    """The override the PMC applied to the coming block."""
    ds[DS_APPLIED] = applied_pct


@compiled
def _advance(dp: np.ndarray, ds: np.ndarray, ratio: float) -> None:
    """The bank one control period on, the feed ``ratio`` (of the programmed) applied."""
    g, pole = dp[D_EXPONENT], dp[D_POLE]
    if ds[DS_STARTED] == 0.0:
        ds[DS_STARTED] = 1.0
        for i in range(HISTORY):
            ds[DS_HIST + i] = ratio
        for m in range(N_MODELS):
            row, at = D_MODELS + m * M_FIELDS, DS_MODELS + m * S_FIELDS
            # the servo at rest at ``ratio`` (unit static gain)
            ds[at + Z1] = (dp[row + M_B2] - dp[row + M_A2]) * ratio
            ds[at + Z0] = ratio - dp[row + M_B0] * ratio
            ds[at + Y] = ratio ** g
    index = (int(ds[DS_AT]) + 1) % HISTORY
    ds[DS_AT] = index
    ds[DS_HIST + index] = ratio
    for m in range(N_MODELS):
        row, at = D_MODELS + m * M_FIELDS, DS_MODELS + m * S_FIELDS
        delay = dp[row + M_DELAY]
        if delay < 0.0:
            continue
        whole = int(delay)
        frac = delay - whole
        u = ((1.0 - frac) * ds[DS_HIST + (index - whole) % HISTORY]
             + frac * ds[DS_HIST + (index - whole - 1) % HISTORY])
        out = ds[at + Z0] + dp[row + M_B0] * u
        ds[at + Z0] = ds[at + Z1] + dp[row + M_B1] * u - dp[row + M_A1] * out
        ds[at + Z1] = dp[row + M_B2] * u - dp[row + M_A2] * out
        ds[at + Y] = pole * ds[at + Y] + (1.0 - pole) * pymax(out, 0.0) ** g


@compiled
def _forget(ds: np.ndarray) -> None:
    """Out of the cut: the window starts afresh at the next entry (the alarm holds)."""
    ds[DS_IN_CUT], ds[DS_S1], ds[DS_SF], ds[DS_SFF] = 0.0, 0.0, 0.0, 0.0
    ds[DS_CAUSE], ds[DS_SINCE] = 0.0, 0.0
    for m in range(N_MODELS):
        at = DS_MODELS + m * S_FIELDS
        ds[at + SY:at + S_FIELDS] = 0.0


@compiled
def _sse(ds: np.ndarray, m: int) -> float:
    """Member m's residual sum of squares under ``F = K y + c``."""
    at = DS_MODELS + m * S_FIELDS
    s1, sf, sy, syy, syf = ds[DS_S1], ds[DS_SF], ds[at + SY], ds[at + SYY], ds[at + SYF]
    det = s1 * syy - sy * sy
    if not det > 0.0:
        return math.inf
    k = (s1 * syf - sy * sf) / det
    c = (sf - k * sy) / s1
    return pymax(ds[DS_SFF] - k * syf - c * sf, 1e-12 * ds[DS_SFF])


@compiled
def _effective(ds: np.ndarray, m: int) -> float:
    """The window's effective count of independent samples under member m: its residual's
    lag-one autocorrelation rho, n (1 - rho) / (1 + rho) (Bartlett)."""
    at = DS_MODELS + m * S_FIELDS
    squares: float = ds[at + SRR]
    rho = pymin(pymax(ds[at + SR1] / squares, 0.0), 0.98) if squares > 0.0 else 0.0
    count: float = ds[DS_S1]
    return count * (1.0 - rho) / (1.0 + rho)


@compiled
def _eligible(dp: np.ndarray, m: int) -> bool:
    """Member m in the bank and outside the identified value's uncertainty."""
    row = D_MODELS + m * M_FIELDS
    if dp[row + M_DELAY] < 0.0:
        return False
    cause, size, z = int(dp[row + M_CAUSE]), float(dp[row + M_SIZE]), float(dp[D_SIGMAS])
    if cause == DEAD_TIME:
        return abs(size) > z * float(dp[D_DEAD_STD])
    return abs(math.log(size)) > z * float(dp[D_SERVO_STD])


@compiled
def _level(dp: np.ndarray, ds: np.ndarray, m: int, n_eff: float
           ) -> tuple[float, float, float, float, float, float]:
    """The level test on member m: cause (NONE where neither a gain nor an offset
    explains the force better than the identified model), size, its standard deviation, the
    ratio statistic, and the other one's reading and its standard deviation (0: none) where
    the window cannot tell a gain from an offset (their own ratio statistic below the
    threshold: a cut at one feed shows a level more than its cause; the one that fits better
    is named first)."""
    at = DS_MODELS + m * S_FIELDS
    s1, sf, sff = ds[DS_S1], ds[DS_SF], ds[DS_SFF]
    sy, syy, syf = ds[at + SY], ds[at + SYY], ds[at + SYF]
    nothing = (float(NONE), 0.0, 0.0, 0.0, 0.0, 0.0)
    if not syy > 0.0:
        return nothing
    z = dp[D_SIGMAS]
    k_hat = syf / syy
    k_id = pymin(pymax(k_hat, dp[D_K_LO]), dp[D_K_HI])
    sse_id = pymax(sff - 2.0 * k_id * syf + k_id * k_id * syy, 1e-12 * sff)
    sse_gain = pymax(sff - syf * syf / syy, 1e-12 * sff)
    offset = (sf - k_id * sy) / s1
    sse_offset = pymax(sse_id - s1 * offset * offset, 1e-12 * sff)
    # the identified model's own error on a predicted force, and on the friction's share
    sigma_k = dp[D_K_STD]
    sigma_c = math.sqrt((dp[D_FRICTION_STD] * dp[D_FRICTION]) ** 2
                        + (sigma_k * sf / s1) ** 2)
    gain = abs(k_hat / k_id - 1.0) > z * sigma_k
    # a friction drift, as far as the estimator's re-zero would follow one
    friction = (dp[D_FRICTION] > 0.0 and abs(offset) > z * sigma_c
                and abs(offset) <= dp[D_FRICTION_MAX] * dp[D_FRICTION])
    if not (gain or friction):
        return nothing
    statistic = n_eff * math.log(sse_id / pymin(sse_gain, sse_offset))
    gain_size, friction_size = k_hat / k_id - 1.0, offset / dp[D_FRICTION] if friction else 0.0
    friction_std = sigma_c / dp[D_FRICTION] if friction else 0.0
    apart = n_eff * abs(math.log(sse_gain / sse_offset)) > z * z
    first_friction = friction and (sse_offset < sse_gain or not gain)
    if first_friction:
        alt, alt_std = (gain_size, sigma_k) if gain and not apart else (0.0, 0.0)
        return float(FRICTION), friction_size, friction_std, statistic, alt, alt_std
    alt, alt_std = (friction_size, friction_std) if friction and not apart else (0.0, 0.0)
    return float(GAIN), gain_size, sigma_k, statistic, alt, alt_std


@compiled
def drift_step(dp: np.ndarray, ds: np.ndarray, force: float, engaged: bool,
               held: float) -> None:
    """One control period: the bank on the override applied to this block (``held`` where
    none was told), the window on the estimated ``force`` while ``engaged``, the tests."""
    if dp[D_ON] == 0.0:
        return
    applied = ds[DS_APPLIED] if math.isfinite(ds[DS_APPLIED]) else held
    if not math.isfinite(applied):
        return
    _advance(dp, ds, applied / 100.0)
    if not (engaged and math.isfinite(force)):
        _forget(ds)
        return
    h = dp[D_PERIOD]
    ds[DS_IN_CUT] += h
    if ds[DS_IN_CUT] < dp[D_SETTLE]:
        return
    lam = dp[D_FORGET]
    ds[DS_S1] = lam * ds[DS_S1] + 1.0
    ds[DS_SF] = lam * ds[DS_SF] + force
    ds[DS_SFF] = lam * ds[DS_SFF] + force * force
    s1, sf = ds[DS_S1], ds[DS_SF]
    for m in range(N_MODELS):
        at = DS_MODELS + m * S_FIELDS
        y = ds[at + Y]
        ds[at + SY] = lam * ds[at + SY] + y
        ds[at + SYY] = lam * ds[at + SYY] + y * y
        ds[at + SYF] = lam * ds[at + SYF] + y * force
        # the member's residual now, for its lag-one autocorrelation
        sy, syy = ds[at + SY], ds[at + SYY]
        det = s1 * syy - sy * sy
        k = (s1 * ds[at + SYF] - sy * sf) / det if det > 0.0 else 0.0
        residual = force - k * y - (sf - k * sy) / s1
        ds[at + SRR] = lam * ds[at + SRR] + residual * residual
        ds[at + SR1] = lam * ds[at + SR1] + residual * ds[at + RPREV]
        ds[at + RPREV] = residual
    if s1 < (1.0 - math.exp(-1.0)) / (1.0 - lam):   # a window's worth of the cut, first
        return
    threshold = dp[D_SIGMAS] * dp[D_SIGMAS]
    sse0 = _sse(ds, 0)
    best, best_sse = 0, sse0
    for m in range(1, N_MODELS):
        if _eligible(dp, m):
            sse = _sse(ds, m)
            if sse < best_sse:
                best, best_sse = m, sse
    cause, size, std, alt = NONE, 0.0, 0.0, 0.0
    if best != 0 and _effective(ds, best) * math.log(sse0 / best_sse) > threshold:
        row = D_MODELS + best * M_FIELDS
        cause, size = int(dp[row + M_CAUSE]), dp[row + M_SIZE]
        # half the bank's step either way
        std = 0.5 * h if cause == DEAD_TIME else 0.5 * (SERVO_RATIO - 1.0) * size
    else:
        # on the identified member: no lag drift found
        level = _level(dp, ds, 0, _effective(ds, 0))
        if level[0] != NONE and level[3] > threshold:
            cause, size, std, alt = int(level[0]), level[1], level[2], level[4]
            if alt != 0.0 and int(ds[DS_CAUSE]) == GAIN + FRICTION - cause:
                # undecided between the two: the attribution standing stays
                cause, size, std, alt = GAIN + FRICTION - cause, alt, level[5], size
    standing = int(ds[DS_CAUSE])
    levels = cause in (GAIN, FRICTION) and standing in (GAIN, FRICTION)
    if cause == NONE or (cause != standing and not levels):
        ds[DS_CAUSE], ds[DS_SINCE] = cause, 0.0
        return
    # a level drift stands while its attribution to gain or friction changes: the alarm
    # names the one that explains the window best now
    ds[DS_CAUSE], ds[DS_SIZE] = cause, size
    ds[DS_SINCE] += h
    if ds[DS_SINCE] >= dp[D_MEMORY]:
        if int(ds[DS_ALARM]) != cause:
            ds[DS_ALARMS] += 1.0
        ds[DS_ALARM], ds[DS_ALARM_SIZE], ds[DS_ALARM_STD] = cause, size, std
        ds[DS_ALARM_ALT] = alt


def alarm(ds: FloatArray) -> tuple[int, float, float, float]:
    """The alarm in the monitor's state: cause, size, standard deviation, the other reading of
    a level (:func:`drift_text` takes them)."""
    return (int(ds[DS_ALARM]), float(ds[DS_ALARM_SIZE]), float(ds[DS_ALARM_STD]),
            float(ds[DS_ALARM_ALT]))


def drift_text(c: ControllerBase, cause: int, size: float, std: float, alt: float = 0.0) -> str:
    """The alarm in words: what drifted, identified and now, and what to do (``alt``: the
    other reading of a level, where the cut cannot tell a gain from a friction drift)."""
    if cause == DEAD_TIME:
        was = c.model_dead_time_s
        what = (f'PMC dead time {size * 1e3:+.0f} ms (identified {was * 1e3:.0f} ms, now '
                f'{(was + size) * 1e3:.0f} +- {std * 1e3:.0f} ms)')
    elif cause == SERVO:
        what = (f'servo {"slower" if size > 1.0 else "faster"}: time scale x{size:.2f} '
                f'(identified 1.00, now {size:.2f} +- {std:.2f})')
    elif cause in (GAIN, FRICTION):
        what = (f'{CAUSES[cause]} {size * 100.0:+.0f} % (identified 1.00, now {1.0 + size:.2f} '
                f'+- {std:.2f})')
        if alt:
            what += (f', or {CAUSES[FRICTION if cause == GAIN else GAIN]} {alt * 100.0:+.0f} % '
                     '(a cut at one feed shows a level more than its cause; an air move '
                     're-zeroes the friction and tells)')
    else:
        return ''
    return f'{what}: re-commission (identify this session)'
