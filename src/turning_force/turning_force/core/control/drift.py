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
exponentially weighted window of ``drift_memory_s`` in the cut, each member's force is fitted
as ``F = K y + c`` by least squares (and, from a tau_c after an entry, with the process lag's
free decay since: :data:`LAG_SETTLE`), on each segment of the window by itself: an entry, a
step in the force that no member follows (a depth step, :func:`_stepped`) or a correction of
the estimate starts a segment, and the lag test sums each member's residual over the
window's segments
(:func:`_segment`). Three tests follow, each a likelihood ratio on the residual's sum of
squares, its effective sample count taken from the residual's lag-one autocorrelation
``rho`` (Bartlett: ``n_eff = n (1 - rho) / (1 + rho)``; ``rho`` at most :data:`RHO_MAX`,
the estimate's own noise: what the best member leaves more correlated than that is slow
misfit), against ``drift_sigmas`` squared (chi-square, one degree of freedom; Basseville &
Nikiforov, Detection of Abrupt Changes, 1993, Sec. 4.2 and 7.2):

- the lag: the best member of the bank against the identified one (PMC dead time or servo),
  each fitted with its gain ramping in the window, ``F = K y + R t y + c`` (a taper's depth
  grows the gain through every window; fitted with one gain, that ramp was the larger part
  of every member's residual, and no lag drift on a taper was named), and with the process
  lag's decay after the segment's start, ``+ E exp(-t / tau_c)``;
- the level, on the member that fits best: the gain ``F = K y`` against the identified
  ``F = K_id y`` (process gain, ``K / K_id``), or an offset ``F = K_id y + c`` (the feed-drive
  friction the estimator subtracts: ``c`` over the identified friction's share of the force);
  where the job's depths span a range of K_s d, ``K_id`` is the nearest end of that range.

The force gives the product K_s d, never K_s alone: on a job over several depths, a gain drift
at one depth is another depth (a 1 mm cut 40 % harder is a 1.4 mm cut) until the force leaves
the job's range. Where the depth is known, it is not: at the job's start (``drift_first_s`` of
cutting, until its program's first depth change, ``identify --job`` writes it with the depth
there as ``drift_ksd_first_*``) ``K_id`` is that depth's.

The friction is measured, not inferred, where the tool is in air: the estimator's re-zero
(:func:`drift_rezeroed`) gives its scale on the identified curve, and a scale outside the
identified friction's uncertainty (for REZERO_STAND_S of the reading) is the friction drift.
Without an air move, a friction drift is an offset of a few percent of the cut's force: at the
job's start, where the depth is known, it stands out of the process model's own error
(:func:`model_error`, a fraction of a percent on the generated machines), but at one feed it
is also a gain of a few percent. The alarm names both, the friction first until a re-zero has
measured it (the one the loop has not checked since commissioning); a re-zero that finds the
friction unchanged turns it to the gain.

Members within ``drift_sigmas`` standard deviations of the identified value, and gains or
offsets within that many of the identified process model's own error (the slow part of its
residual in the commissioning cut, its parameters' standard deviations, and after a re-zero
the friction's as read in air), are not drift; nor is an offset
larger than the friction change the estimator's re-zero would follow
(``drift_friction_max_change``, its ``rezero_max_change``). Where the window cannot tell a gain
from an offset (a cut at one depth and feed shows a level more than its cause), the alarm
names both, as above. A cause raises the
alarm once it has stood for ``drift_memory_s`` of cutting (an air move pauses the count); the
alarm holds (a drift is the machine's, not the cut's) until another cause is found, or the tool
changes (:func:`drift_tool`: another tool, another identified model).

The monitor acts on one cause: a friction drift read in the cut, which the estimator then takes
off its estimate (:func:`drift_correction`, the estimator's ``estimator_correct``), as an air
move's re-zero would; ``drift_friction_correction`` says which readings: those the window tells
from a gain (``decided``), or every one named (``named``: an undecided level that was a gain
of a few percent holds the force that much above the reference until an air move re-zeroes
the friction), or none. A correction starts a segment of the window, and a friction left over
is read and corrected a window later.

A lag drift (PMC dead time, servo) the monitor names is a member of its bank: where
``drift_adopt_model`` is on, a law that predicts with the machine's model (the predictive law,
:mod:`.laws.mpc`; the sliding mode law's Smith predictor, :mod:`.predictor`) takes that
member's dead time and servo into its own model from the alarm on, until the tool changes
(``update.controller_update`` calls the law's ``adopt``); the alarm says so (:func:`adopted`,
:func:`adopted_text`, :func:`drift_text`), and so do the core loop's trace (``drift_adopted``,
``drift_adopted_size``) and ``force_controller``'s ``/diagnostics`` (``model``). The monitor
itself goes on comparing the machine with the identified model.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core import lti
from turning_force.core.compiled import compiled, pymax, pymin

if TYPE_CHECKING:
    from turning_force.core.control.law import ControllerBase
    from turning_force.core.experiment import Experiment
    from turning_force.core.identify import Identification
    from turning_force.core.plant.settings import DepthProfile

__all__ = ['CAUSES', 'CORRECTIONS', 'PARAMS', 'STATE', 'adopted', 'adopted_text', 'alarm',
           'drift_applied',
           'drift_correction', 'drift_fill', 'drift_rezeroed', 'drift_step', 'drift_text',
           'drift_tool', 'first_cut', 'identified', 'model_error']

FloatArray = npt.NDArray[np.float64]

# The bank: dead time offsets [control periods] and servo time scales SERVO_RATIO^k, x0.56
# to x2.59. The member nearest a servo drift misses it by up to half a step, and what it
# leaves is slow misfit, its lag-one correlation at RHO_MAX: the lag test needs that member
# to leave a twentieth of the identified one's residual. At x1.2 steps a drift halfway
# between two members did not: on a second-order servo slowed x1.30 (between x1.2 and
# x1.44) the x1.2 member left an eighth, a statistic of 10 against 16 once the entry's
# transient was in the window, and the drift was named only from a depth step's transient
# 8.5 s in, each step ringing on the old model until then (population seed 15, #152, the
# 'steps' job; its x1.33 member at x1.1 steps names it 2.2 s in, as on x1.3 exactly).
DEAD_OFFSETS = (-4, -3, -2, -1, 1, 2, 3, 4, 5, 6, 7, 8)
SERVO_RATIO = 1.1
SERVO_POWERS = (-6, -5, -4, -3, -2, -1, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10)
N_MODELS = 1 + len(DEAD_OFFSETS) + len(SERVO_POWERS)
# What drifted (the alarm's code, the trace's ``drift_alarm``).
NONE, DEAD_TIME, SERVO, GAIN, FRICTION = range(5)
CAUSES = ('', 'PMC dead time', 'servo', 'process gain', 'friction')
# Which friction readings in the cut the estimator is corrected by (drift_friction_correction):
# none, those the window tells from a gain, every one named (the undecided ones too).
CORRECTIONS = ('none', 'decided', 'named')
FIRST_RAMP_S = 3.0   # a job that starts on a taper: its first seconds count as its start
# The re-zero reads the friction at the air move's feed through the identified curve's shape,
# which the commissioning cut fitted at its own feeds: its relative error there, one standard
# deviation (up to 4 % on generated machines that did not change, bench_drift.py seed 16).
REZERO_STD = 0.025
# A re-zero's reading names the friction drift once it has stood beyond the band this long in
# a row [s]: a drift's scale, converging through the air move, stays beyond once it got there;
# a feed's transient does not. On population seed 15's #101 (undrifted; an interrupted job on
# a servo of zeta 0.31) the feed rang down to a stop in the air move, and the readings through
# the stick region read half the friction for 0.05 s (the scale at its clamp, 0.5), named
# "friction -50 %" at once, while the move's later readings gave 1.014-1.026.
REZERO_STAND_S = 0.1
HISTORY = 64   # control periods of applied override kept (the longest delay in the bank)
# The largest lag-one autocorrelation the effective sample count takes from a residual. The
# Kalman estimate's own noise is correlated up to about 0.9 from one control period to the
# next (0.4-0.9 in the residual where the identified model fits, bench_drift.py seeds 16 and
# 29); a residual more correlated than that is slow misfit (the bank's own step: the member
# nearest a drift misses it by up to half a step; the identified model's error), the same in
# the members compared, which makes a drift no less likely. At 0.9 a 1 s window counts at
# least 5 independent samples (n (1 - rho) / (1 + rho)): the best member must explain all but
# a twentieth of the identified model's residual, exp(-16 / 5.3), to be a lag drift at 4
# sigmas. At 0.6 a gain drift's entry transient is read as a dead time (seed 16, #5).
RHO_MAX = 0.9
# The delay the bank's identified member gives the estimate, in control periods, is known only
# to within the sampled model's hold: a uniform error over +- half a period, its standard
# deviation 1 / sqrt(12). Replayed with fractional offsets, the estimate of unchanged generated
# machines is best fitted 0.5 period earlier to 0.9 period later than the identified member
# (bench_drift.py seeds 16, 29, 37), and where the loop cycles at a low feed the member a period
# longer leaves half the identified one's residual (seed 29 #2 at 3.5 mm and 14 %: a statistic
# of 16.7 against 16): a dead time within drift_sigmas of that is none.
DELAY_STD = 1.0 / math.sqrt(12.0)
# The servo's time scale likewise, to within half a step of the bank's: SERVO_RATIO's log over
# sqrt(12). One step off is no drift, two are (at drift_sigmas 4, x1.1 against x1.21): on
# population seed 15's #195, undrifted, the x0.91 member was named at 6.70 s.
SERVO_STD = math.log(SERVO_RATIO) / math.sqrt(12.0)
# A step in the force that no member follows (a depth step in the program, a harder part of
# the bar: the process gain jumps) starts a segment of the window, as an entry does: fitted
# with one gain and a ramp, a window that straddles the step leaves the same residual on every
# member, and the lag test loses what it had (a long job's 1.5 -> 2.5 mm step took a PMC dead
# time drift's statistic from 17 to 1, bench_drift.py seed 37 #4). The step is the best
# member's residual beyond STEP_SIGMAS of the window's root mean square for STEP_PERIODS
# control periods in a row, with one sign: the estimate's noise, correlated up to RHO_MAX from
# one period to the next, stays within 6 sigmas for 5 periods but once in 1e8.
STEP_SIGMAS = 6.0
# An entry or a depth step reaches the force through the process lag alone (the bank follows
# the feed through dead time and servo all along): after it, F = K y + E exp(-t / tau_c)
# exactly (Park Eq. 1: the lag's input steps, its state decays freely). The lag test fits
# that decay and starts LAG_SETTLE tau_c after the segment's start (the estimate's own
# transient at the step, the gate's entry); the level test waits five tau_c (D_SETTLE), for
# the decay to be gone. The second after an entry is where the loop moves the override most:
# waiting five tau_c there left a slow process (tau_c 0.16-0.18 s) the quiet part, and its
# servo drifts were not named within 5 s (bench_drift.py seed 16 #0 and #2, 29 #4, 37 #3;
# named at 2.2-2.7 s with it, the same at 0.5 and 2 tau_c).
LAG_SETTLE = 1.0
STEP_PERIODS = 5
# The feed test (:func:`_feed_test`): the PMC dead time and the servo, measured on the axis
# feed the DAQ records against the feed each member of the bank gives from the override
# applied, not inferred from the force through the process. The feed is the servo's own
# output: no process lag, no cutting exponent, no estimate's noise between. Over a window of
# FEED_MEMORY_S (in air and in the cut alike) each member's squared residual is summed on the
# block's mean feed, as a fraction of the programmed feed, against the member's mean over the
# block (the trapezoid of its feed at the block's ends: the bank's servo is the zero-order
# hold of the continuous one, exact at the ends). A member outside the identified value's
# uncertainty (:func:`_eligible`) names the drift where it leaves FEED_RATIO times less than
# the identified one, each with FEED_FLOOR's variance added per sample, for FEED_STAND_S in a
# row. On population seed 42's first 60 machines with a 1 s approach (each commissioned as
# the user would, the bank replayed on the blocks their jobs recorded) the ratio reached at
# most 1.9 on the 49 that did not drift in their lag, and 48 to 690 on the 11 whose servo or
# dead time did, the drift named 0.11 to 0.20 s after the first override step in the cut.
# FEED_FLOOR is the bank's own error: a dead time between whole control periods is held
# by interpolating the override (DELAY_STD), which misses the feed by up to a few percent of
# a step's size in the period it arrives; without the floor a member whose delay had not yet
# reached the step (the feed still at rest, its residual 0) stood 1e23 times better than the
# identified one for a period (seed 42 #56, 59 ms). Noise in the measured feed adds to every
# member alike and does not raise the ratio. While the spindle speed changes (G96) faster
# than FEED_RPM_STEADY the test waits: the feed follows the speed through the servo's lag,
# and the bank, on the override alone, does not. The member named must follow the feed:
# its residual's root mean square over the window at most FEED_FIT of the programmed feed
# (on those 11 drifts at most 1.9 % wherever the ratio passed). A feed that follows no
# member is no lag drift: an override the axis does not obey (override cancel, a feed hold,
# a ladder that does not copy the module's inputs to *FV) left the slowest member, whose
# feed had moved least, the best by the ratio, and named a dead time of +80 ms that the law
# took into its model; the gate's feed-follow check (``feed_follow_time_s``) is what hands
# back there.
FEED_MEMORY_S = 0.3
FEED_FLOOR = 0.003
FEED_FIT = 0.05
# And the axis must have moved in the window: the measured feed's standard deviation over it
# at least FEED_MOVE of the programmed feed. Before an override step has come through to the
# axis every member longer than the identified one still holds the feed at rest, as the axis
# does: a residual of nothing, against the identified member's that has begun to move. On an
# axis that never obeys the step (the override cancelled) the longest member stood so for
# its whole extra delay, and was named.
FEED_MOVE = 0.01
FEED_RATIO = 10.0
FEED_STAND_S = 0.05
FEED_RPM_STEADY = 0.02   # [1/s]

# --- parameters (dp) ---------------------------------------------------------------------------
(D_ON, D_PERIOD, D_FORGET, D_SIGMAS, D_POLE, D_EXPONENT, D_SETTLE, D_MEMORY, D_K_LO, D_K_HI,
 D_K_STD, D_FRICTION, D_FRICTION_STD, D_FRICTION_MAX, D_DEAD, D_DEAD_STD, D_SERVO_STD,
 D_FIRST_S, D_K_FIRST_LO, D_K_FIRST_HI, D_CORRECT, D_LAG_SETTLE, D_ADOPT, D_F_FORGET) = range(24)
D_MODELS = 24
# per member: delay [periods], servo b0 b1 b2 a1 a2 (direct form II transposed), cause, size
M_DELAY, M_B0, M_B1, M_B2, M_A1, M_A2, M_CAUSE, M_SIZE = range(8)
M_FIELDS = 8
PARAMS = D_MODELS + N_MODELS * M_FIELDS

# --- state (ds) --------------------------------------------------------------------------------
# the override applied to the coming block (NaN: none told yet), the ring's index, whether the
# bank runs, the time in the cut, the window's sums (weights, F, F^2), the cause standing and
# since when, the alarm (its cause, size, standard deviation), how often it was raised, and
# where the cut cannot tell a gain from a friction drift, the other one's reading, and the time
# in the cut since the monitor was armed (the run's start or the tool's change), how long
# the tests have not found the cause standing, whether the estimator re-zeroed the friction
# (REZ_*) and the scale it read last, the friction the estimator is to take off its
# estimate [N] (drift_correction: 0 none asked), and for how many periods in a row the best
# member's residual has stood beyond STEP_SIGMAS (signed: its sign) of the window's mean
# square before, the window's weight over all its segments (the segment's is DS_S1), and that
# weight where the step's run began; the lag drift (cause, size) the law took into its model
# (drift_adopt_model: update.controller_update; 0: none); how long the re-zero's reading has
# stood beyond the band (REZERO_STAND_S); the cause found through the standing one's lapse,
# and for how long in a row.
# The feed test's (:func:`drift_feed`, :func:`_feed_test`): the block's measured feed (a
# fraction of the programmed feed at the spindle speed in use) and whether one was told for
# this block, the 100 % feed rate the last block was told at, the window's weight, the
# member standing best and for how long, the member the test named (0: none), and whether
# the test has read a feed since the monitor was armed (then the feed, not the force, names
# the lag), and the window's sums of the measured feed and of its square (FEED_MOVE).
(DS_APPLIED, DS_AT, DS_STARTED, DS_IN_CUT, DS_S1, DS_SF, DS_SFF, DS_CAUSE, DS_SIZE,
 DS_SINCE, DS_ALARM, DS_ALARM_SIZE, DS_ALARM_STD, DS_ALARMS, DS_ALARM_ALT,
 DS_CUT_S, DS_LAPSE, DS_REZEROED, DS_SCALE, DS_CORRECT, DS_STEP, DS_STEP_MS, DS_COUNT,
 DS_COUNT_RUN, DS_SQ, DS_SQQ, DS_SQF, DS_L1, DS_LF, DS_LFF, DS_LY, DS_LYY, DS_LYF,
 DS_ADOPTED, DS_ADOPTED_SIZE, DS_BEYOND, DS_NEXT, DS_NEXT_SINCE, DS_FEED, DS_FEED_TOLD,
 DS_F_RATE, DS_FW, DS_F_BEST, DS_F_SINCE, DS_F_NAMED, DS_F_SEEN, DS_F_SUM,
 DS_F_SQ) = range(48)
DS_HIST = 48
# The re-zero: none yet, reading (its scale converging through the air move), a control
# period without a reading (over once a second one passes), read (the last reading stands).
REZ_NONE, REZ_READING, REZ_PAUSED, REZ_READ = range(4)
DS_MODELS = DS_HIST + HISTORY
# per member: servo state z0 z1, output y, the segment's sums y, y^2, y F, and of its
# residual over the window: squared, times the one before, the one before; the segment's sums
# of u = t y (t the time in the segment), u^2, u y, u F; its fit's residual sum of squares this
# period (_fit); the window's earlier segments' (each fitted on its own, decayed since); and
# where a step's run began (_stepped): the segment's, the residual's squared and lag-one sums;
# the member's mean feed over the block (a fraction of the programmed), and its squared
# residual on the measured feed over the feed test's window.
(Z0, Z1, Y, SY, SYY, SYF, SRR, SR1, RPREV, SU, SUU, SUY, SUF, SSE, CARRY, RUN_SSE, RUN_RR,
 RUN_R1, SQY, SQU, FMEAN, FSS) = range(22)
S_FIELDS = 22
STATE = DS_MODELS + N_MODELS * S_FIELDS


def identified(ident: Identification, job: Experiment, depths_mm: tuple[float, float],
               cut_depth_mm: float, program: DepthProfile | None = None
               ) -> dict[str, float | bool]:
    """The ``force_controller`` settings that turn the monitor on for a job cutting
    ``depths_mm`` deep on the machine ``ident`` identified from a cut ``cut_depth_mm`` deep
    (what ``identify`` writes beside the model): K_s d over the job's depths, and the standard
    deviation of each identified value. A force the process model predicts is as uncertain as
    its parameters and as its residual in the commissioning cut (the model error the fit
    left, relative to the job's reference force).

    With the job's depth ``program``, also where the job starts: K_s d over the depths of its
    first :func:`first_cut` seconds. The force gives K_s d, never K_s alone; a gain drift is
    seen where the depth is known, and the program's start is such a place. The friction's
    share is the identified curve's at the feed that holds the reference there
    (:func:`start_feed_mm_min`), where the monitor reads it."""
    ksd = ident.ksd_n_mm
    first_s, first = first_cut(program) if program is not None else (0.0, depths_mm)
    first_s = max(first_s - engagement_s(ident, job, first[0] / cut_depth_mm), 0.0)
    residual = model_error(ident) / job.controller.reference_force_n
    friction_a = float(ident.friction_model.current_a(np.array([start_feed_mm_min(
        ident, job, 0.5 * (first[0] + first[1]) / cut_depth_mm)]))[0])
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
        'drift_first_s': first_s,
        'drift_ksd_first_min_n_mm': ksd.value * first[0] / cut_depth_mm,
        'drift_ksd_first_max_n_mm': ksd.value * first[1] / cut_depth_mm,
    }


def start_feed_mm_min(ident: Identification, job: Experiment, depth_ratio: float) -> float:
    """The feed [mm/min] that holds the job's reference force at ``depth_ratio`` times the
    commissioning cut's depth on the identified process: F = K_s d f_prog o^g (Park Eq. 1
    with Kienzle's exponent) at the override o = (F_ref / (K_s d f_prog))^(1/g), within the
    override table's levels. The monitor reads a friction drift in the cut as an offset at the
    cut's feed, not the programmed one: the friction curve (Park Eq. 25) falls with the feed
    (0.60 A at 6 mm/min, 0.35 A at 300 on the lathe's defaults), and a cut that holds the
    reference at half the programmed feed carries up to 1.4 times the friction the programmed
    feed does (seed 15 #131: a 44 % drift read as 59 % of that, beyond the 50 % a re-zero
    follows: named a process gain)."""
    from turning_force.core.pmc.overrides import get_table

    c = job.controller
    table = get_table(c.override_table)
    full = ident.ksd_n_mm.value * depth_ratio * c.programmed_feed_mm_rev
    g = ident.process['cutting_exponent'].value
    override = (c.reference_force_n / full) ** (1.0 / g) if full > 0.0 else 1.0
    override = min(max(override, table.min_pct / 100.0), table.max_pct / 100.0)
    return override * c.programmed_feed_rate_mm_min


def engagement_s(ident: Identification, job: Experiment, depth_ratio: float) -> float:
    """How long after the program's start the cut's clock starts: the tool enters at the
    level the axis approached at (``approach_override_pct``), and the gate counts it in the cut
    once the force, rising with tau_c (Park 1998 Eq. 1) to ``K_s d (level)^g``, passes
    ``engage_force_n``. The monitor's clock runs from there, the program's from the entry: at
    Park's 1 mm and a 30 % entry feed, 1.4 tau_c apart. 0 where the force there would not
    pass it."""
    level = job.plant.approach_override_pct / 100.0
    steady = (ident.ksd_n_mm.value * depth_ratio * job.controller.programmed_feed_mm_rev
              * level ** ident.process['cutting_exponent'].value)
    engage = job.bridge.engage_force_n
    if not steady > engage:
        return 0.0
    return ident.process['cutting_time_constant_s'].value * math.log(steady / (steady - engage))


def model_error(ident: Identification) -> float:
    """The identified process model's own error on a force [N]: the slow part of its residual
    in the commissioning cut, what is left of the residual's variance once the white noise of
    one force sample (``force_noise_n``, from the differences of neighbouring samples) is taken
    out of it, plus one standard deviation of that difference (each variance known to
    ``2 sigma std(sigma)``: on the generated machines the white noise is most of the residual,
    and the difference is that uncertainty). The white noise averages out over the monitor's
    window, whose own statistic counts it; the slow part (a curve the model missed) does
    not."""
    rms, white = ident.process.residual_rms, ident.force_noise_n
    slow = max(rms * rms - white.value * white.value, 0.0)
    return math.sqrt(slow + 2.0 * math.sqrt(2.0) * white.value * white.std)


def first_cut(program: DepthProfile) -> tuple[float, tuple[float, float]]:
    """The job's start, where its depth is known: the time in the cut [s] until the program's
    first depth change, and the depth [mm] there; where it starts on a taper, its first
    FIRST_RAMP_S and the depths [mm] it ramps over. 0 s where the depth never changes (the
    job's range is its start's). A program that approaches the work in air starts at its first
    contact. The simulator's program runs in time; a real one runs in distance, and reaches
    its first change later where the override is below 100 %."""
    depths_mm = program.depth_mm
    contact = next((k for k, depth in enumerate(depths_mm) if depth > 0.0), 0)
    if contact > 0:   # the approach in air: the program from its first contact
        start = program.times_s[contact]
        program = replace(program, times_s=tuple(t - start for t in program.times_s[contact:]),
                          depth_mm=depths_mm[contact:])
    changes = program.change_times_s()
    if not changes or program.depth_mm[0] <= 0.0:   # one depth, or all in air
        return 0.0, (program.depth_mm[0], program.depth_mm[0])
    if changes[0] > 0.0:
        return changes[0], (program.depth_mm[0], program.depth_mm[0])
    depths = program.at(np.linspace(0.0, FIRST_RAMP_S, 31))
    return FIRST_RAMP_S, (float(depths.min()), float(depths.max()))


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
    p[D_LAG_SETTLE] = LAG_SETTLE * c.model_cutting_time_constant_s
    # the force at the programmed feed (y = 1) over the job's K_s d range
    feed = c.programmed_feed_mm_rev
    p[D_K_LO], p[D_K_HI] = c.drift_ksd_min_n_mm * feed, c.drift_ksd_max_n_mm * feed
    p[D_K_STD] = c.drift_ksd_std
    p[D_FRICTION], p[D_FRICTION_STD] = c.drift_friction_n, c.drift_friction_std
    p[D_FRICTION_MAX] = c.drift_friction_max_change
    # the bank's sampled model reads the machine's delay to within its hold (DELAY_STD)
    p[D_DEAD] = c.model_dead_time_s
    p[D_DEAD_STD] = math.hypot(c.drift_dead_time_std_s, DELAY_STD * h)
    p[D_SERVO_STD] = math.hypot(c.drift_servo_std, SERVO_STD)   # the bank's step (SERVO_STD)
    p[D_FIRST_S] = c.drift_first_s
    p[D_K_FIRST_LO] = c.drift_ksd_first_min_n_mm * feed
    p[D_K_FIRST_HI] = c.drift_ksd_first_max_n_mm * feed
    p[D_CORRECT] = CORRECTIONS.index(c.drift_friction_correction)
    p[D_ADOPT] = c.drift_adopt_model
    p[D_F_FORGET] = math.exp(-h / FEED_MEMORY_S) if c.drift_feed_test else 0.0   # 0: off
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
def drift_feed(ds: np.ndarray, feed_mm_min: float, full_mm_min: float, period_s: float
               ) -> None:
    """The axis feed the DAQ measured over the coming block [mm/min] (its mean), the 100 %
    override's feed rate at the spindle speed in use ``full_mm_min``: the feed test's reading
    (:func:`_feed_test`), none where either is not finite or the spindle speed moved faster
    than FEED_RPM_STEADY since the last block."""
    before = ds[DS_F_RATE]
    ds[DS_F_RATE] = full_mm_min
    ds[DS_FEED_TOLD] = 0.0
    if not (math.isfinite(feed_mm_min) and math.isfinite(full_mm_min) and full_mm_min > 0.0):
        return
    if before > 0.0 and abs(full_mm_min / before - 1.0) > FEED_RPM_STEADY * period_s:
        return
    ds[DS_FEED], ds[DS_FEED_TOLD] = feed_mm_min / full_mm_min, 1.0


@compiled
def _feed_test(dp: np.ndarray, ds: np.ndarray) -> None:
    """The feed test, once the bank has advanced over the block the measured feed covers:
    each member's residual on it into the window, and the member that names a lag drift
    (FEED_RATIO, FEED_FLOOR, FEED_FIT, FEED_MOVE, FEED_STAND_S) raised as the alarm; that
    member is the one the force's level test reads the process on from then (a new segment).
    The feed told is spent."""
    if ds[DS_FEED_TOLD] == 0.0 or dp[D_F_FORGET] == 0.0:
        return
    ds[DS_FEED_TOLD] = 0.0
    ds[DS_F_SEEN] = 1.0
    measured, lam = ds[DS_FEED], dp[D_F_FORGET]
    ds[DS_FW] = lam * ds[DS_FW] + 1.0
    ds[DS_F_SUM] = lam * ds[DS_F_SUM] + measured
    ds[DS_F_SQ] = lam * ds[DS_F_SQ] + measured * measured
    for m in range(N_MODELS):
        if dp[D_MODELS + m * M_FIELDS + M_DELAY] < 0.0:
            continue
        at = DS_MODELS + m * S_FIELDS
        residual = measured - ds[at + FMEAN]
        ds[at + FSS] = lam * ds[at + FSS] + residual * residual
    floor = ds[DS_FW] * FEED_FLOOR * FEED_FLOOR
    sse0 = ds[DS_MODELS + FSS]
    best, best_sse = _best(dp, ds, True)
    mean = ds[DS_F_SUM] / ds[DS_FW]
    moved = ds[DS_F_SQ] / ds[DS_FW] - mean * mean >= FEED_MOVE * FEED_MOVE
    if (best == 0 or not moved or sse0 + floor <= FEED_RATIO * (best_sse + floor)
            or best_sse > ds[DS_FW] * FEED_FIT * FEED_FIT):
        ds[DS_F_BEST], ds[DS_F_SINCE] = 0.0, 0.0
        return
    h = dp[D_PERIOD]
    if int(ds[DS_F_BEST]) == best:
        ds[DS_F_SINCE] += h
    else:
        ds[DS_F_BEST], ds[DS_F_SINCE] = best, h
    if ds[DS_F_SINCE] < FEED_STAND_S - 1e-9 or int(ds[DS_F_NAMED]) == best:
        return
    ds[DS_F_NAMED] = best
    row = D_MODELS + best * M_FIELDS
    cause, size = int(dp[row + M_CAUSE]), dp[row + M_SIZE]
    # half the bank's step either way
    std = 0.5 * h if cause == DEAD_TIME else 0.5 * (SERVO_RATIO - 1.0) * size
    _raise(ds, cause, size, std, 0.0)
    _segment(ds)


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
        # the feed over the block: from ``out`` at its start to Z0 at its end (the zero-order
        # hold of a strictly proper servo has b0 = 0: the end does not wait on the next input)
        ds[at + FMEAN] = 0.5 * (out + ds[at + Z0])


@compiled
def _segment(ds: np.ndarray) -> None:
    """The segment ends (the tool left the cut, a step in the force, a correction of the
    estimate): each member's fit of it stays in the window as its residual sum of squares
    (CARRY, decaying with the window's weight as the cut goes on), and the next segment, from
    a tau_c on (LAG_SETTLE), is fitted with its own gain, ramp, offset and decay. The
    lag test compares the members over every segment in the window (a long job's depth steps,
    an interrupted cut's entries); the level test reads the segment (one depth, one
    friction). The alarm holds, and so does a cause standing: its time counts in the cut,
    and an air move pauses it."""
    ds[DS_IN_CUT], ds[DS_S1], ds[DS_SF], ds[DS_SFF] = 0.0, 0.0, 0.0, 0.0
    ds[DS_SQ:DS_LYF + 1] = 0.0
    for m in range(N_MODELS):
        at = DS_MODELS + m * S_FIELDS
        if math.isfinite(ds[at + SSE]):
            ds[at + CARRY] += ds[at + SSE]
        ds[at + SY:at + SRR] = 0.0
        ds[at + RPREV:at + CARRY] = 0.0
        ds[at + SQY], ds[at + SQU] = 0.0, 0.0


@compiled
def _window_sse(ds: np.ndarray, m: int) -> float:
    """Member m's residual sum of squares over the window: its segments' fits."""
    at = DS_MODELS + m * S_FIELDS
    sse: float = ds[at + SSE]
    carried: float = ds[at + CARRY]
    return carried + (sse if math.isfinite(sse) else 0.0)


@compiled
def _stepped(ds: np.ndarray, m: int, sse: float) -> bool:
    """Whether member m's residual now completes a step (:data:`STEP_SIGMAS`,
    :data:`STEP_PERIODS`): the window no longer fits the force since. The residual is measured
    against the window's mean square from before the run began: the step's own samples,
    fitted into the window as they come, would raise it past them within a few periods."""
    residual = ds[DS_MODELS + m * S_FIELDS + RPREV]
    run = ds[DS_STEP]
    if run == 0.0:
        ds[DS_STEP_MS] = sse / ds[DS_COUNT]
    if not residual * residual > STEP_SIGMAS * STEP_SIGMAS * ds[DS_STEP_MS]:
        ds[DS_STEP] = 0.0
        return False
    sign = math.copysign(1.0, residual)
    run = run + sign if run * residual > 0.0 else sign
    ds[DS_STEP] = run
    if abs(run) < STEP_PERIODS:
        return False
    ds[DS_STEP] = 0.0
    return True


@compiled
def _unstep(ds: np.ndarray, lam: float, periods: float) -> None:
    """A step's run of ``periods`` is over (or the tool left the cut in one): the segment
    ends where the run began, the run's own samples (the force stepping, which no member
    follows) out of every sum (decayed since)."""
    ds[DS_STEP] = 0.0
    decay = lam ** periods
    ds[DS_COUNT] = ds[DS_COUNT_RUN] * decay
    for m in range(N_MODELS):
        at = DS_MODELS + m * S_FIELDS
        ds[at + SSE] = ds[at + RUN_SSE] * decay
        ds[at + SRR], ds[at + SR1] = ds[at + RUN_RR] * decay, ds[at + RUN_R1] * decay
    _segment(ds)


@compiled
def _fit(ds: np.ndarray, m: int) -> tuple[float, float, float, float, float]:
    """Member m's least squares fit over the segment, ``F = K y + R t y + c + E q`` (q the
    process lag's decay from the segment's start, :data:`LAG_SETTLE`): K, R, c, E and the
    residual sum of squares (inf where it cannot fit). A column the segment cannot tell
    from those before it (the ramp and the decay in its first samples) is left out: its
    pivot in the Cholesky factor of the normal equations, in the order y, 1, t y, q, below
    1e-9 of its diagonal."""
    at = DS_MODELS + m * S_FIELDS
    a = np.empty((4, 4))
    b = np.empty(4)
    a[0, 0], a[0, 1], a[0, 2], a[0, 3] = ds[at + SYY], ds[at + SY], ds[at + SUY], ds[at + SQY]
    a[1, 1], a[1, 2], a[1, 3] = ds[DS_S1], ds[at + SU], ds[DS_SQ]
    a[2, 2], a[2, 3] = ds[at + SUU], ds[at + SQU]
    a[3, 3] = ds[DS_SQQ]
    b[0], b[1], b[2], b[3] = ds[at + SYF], ds[DS_SF], ds[at + SUF], ds[DS_SQF]
    for i in range(4):
        for j in range(i):
            a[i, j] = a[j, i]
    low = np.zeros((4, 4))
    kept = np.zeros(4)
    z = np.zeros(4)
    sff = ds[DS_SFF]
    sse = sff
    for j in range(4):
        d = a[j, j]
        for k in range(j):
            d -= low[j, k] * low[j, k]
        if not (a[j, j] > 0.0 and d > 1e-9 * a[j, j]):
            if j < 2:
                return 0.0, 0.0, 0.0, 0.0, math.inf
            continue
        kept[j] = 1.0
        low[j, j] = math.sqrt(d)
        for i in range(j + 1, 4):
            v = a[i, j]
            for k in range(j):
                v -= low[i, k] * low[j, k]
            low[i, j] = v / low[j, j]
        v = b[j]
        for k in range(j):
            v -= low[j, k] * z[k]
        z[j] = v / low[j, j]
        sse -= z[j] * z[j]
    theta = np.zeros(4)
    for j in range(3, -1, -1):
        if kept[j] == 0.0:
            continue
        v = z[j]
        for i in range(j + 1, 4):
            v -= low[i, j] * theta[i]
        theta[j] = v / low[j, j]
    return theta[0], theta[2], theta[1], theta[3], pymax(sse, 1e-12 * sff)


@compiled
def _effective(ds: np.ndarray, m: int, count: float) -> float:
    """The effective count of independent samples of ``count`` under member m: its residual's
    lag-one autocorrelation rho, n (1 - rho) / (1 + rho) (Bartlett)."""
    at = DS_MODELS + m * S_FIELDS
    squares: float = ds[at + SRR]
    rho = pymin(pymax(ds[at + SR1] / squares, 0.0), RHO_MAX) if squares > 0.0 else 0.0
    return count * (1.0 - rho) / (1.0 + rho)


@compiled
def _best(dp: np.ndarray, ds: np.ndarray, feed: bool) -> tuple[int, float]:
    """The member that leaves the least residual, of the identified one (0) and those outside
    its uncertainty (:func:`_eligible`), and that residual: on the measured feed over the feed
    test's window (``feed``), or on the force over the window's segments."""
    best, best_sse = 0, ds[DS_MODELS + FSS] if feed else _window_sse(ds, 0)
    for m in range(1, N_MODELS):
        if _eligible(dp, m):
            sse = ds[DS_MODELS + m * S_FIELDS + FSS] if feed else _window_sse(ds, m)
            if sse < best_sse:
                best, best_sse = m, sse
    return best, best_sse


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
def _level(dp: np.ndarray, ds: np.ndarray, m: int, n_eff: float, k_lo: float, k_hi: float
           ) -> tuple[float, float, float, float, float, float]:
    """The level test on member m, the identified gain within [k_lo, k_hi]: cause (NONE
    where neither a gain nor an offset explains the force better than the identified model),
    size, its standard deviation, the ratio statistic, and the other one's reading and its
    standard deviation (0: none) where the window cannot tell a gain from an offset (their
    own ratio statistic below the threshold: a cut at one feed shows a level more than its
    cause; the friction is named first until a re-zero has measured it, the gain after)."""
    s1, sf, sff = ds[DS_L1], ds[DS_LF], ds[DS_LFF]
    sy, syy, syf = ds[DS_LY], ds[DS_LYY], ds[DS_LYF]
    nothing = (float(NONE), 0.0, 0.0, 0.0, 0.0, 0.0)
    if not syy > 0.0:
        return nothing
    z = dp[D_SIGMAS]
    k_hat = syf / syy
    k_id = pymin(pymax(k_hat, k_lo), k_hi)
    sse_id = pymax(sff - 2.0 * k_id * syf + k_id * k_id * syy, 1e-12 * sff)
    sse_gain = pymax(sff - syf * syf / syy, 1e-12 * sff)
    offset = (sf - k_id * sy) / s1
    sse_offset = pymax(sse_id - s1 * offset * offset, 1e-12 * sff)
    # the identified model's own error on a predicted force, and on the friction's share
    sigma_k = dp[D_K_STD]
    # after a re-zero the estimator subtracts the friction it read in air, as uncertain as
    # that reading (REZERO_STD), not the identified curve
    read = pymax(dp[D_FRICTION_STD], REZERO_STD if ds[DS_REZEROED] != REZ_NONE else 0.0)
    sigma_c = math.sqrt((read * dp[D_FRICTION]) ** 2 + (sigma_k * sf / s1) ** 2)
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
    # Undecided (not apart), the friction is named first until an air move has re-zeroed it:
    # the estimator subtracts a friction no one has measured since commissioning, and a
    # re-zero that finds it unchanged turns the level to the gain (drift_rezeroed). The cut
    # cannot decide it: fitting F = K y + c freely over a job's start at one depth, the
    # intercept c of the unchanged generated machines is -82 to +4 N, 2 to 62 N its standard
    # error (where y spans a few percent; where it spans more, the estimator's lag biases the
    # slope), where a 25 % friction drift is 15 to 23 N (bench_drift.py seeds 16 and 29).
    if friction and gain and not apart:
        first_friction = ds[DS_REZEROED] == REZ_NONE
    else:
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
    if ds[DS_REZEROED] == REZ_READING:
        ds[DS_REZEROED] = REZ_PAUSED
    elif ds[DS_REZEROED] == REZ_PAUSED:
        _read(dp, ds)
    told = math.isfinite(ds[DS_APPLIED])
    if ds[DS_STARTED] == 0.0 and not told:
        # the bank starts at rest at the first level the PMC is told to have applied: the
        # controller's own ``held`` is no reading of where the axis is (it approached the work
        # at the PMC's level in air, the entry feed where there is one)
        return
    applied = ds[DS_APPLIED] if told else held
    if not math.isfinite(applied):
        return
    _advance(dp, ds, applied / 100.0)
    _feed_test(dp, ds)
    if not (engaged and math.isfinite(force)):
        if ds[DS_STEP] != 0.0:   # the force fell out of the window's fit as the tool left
            _unstep(ds, dp[D_FORGET], abs(ds[DS_STEP]))
        _segment(ds)
        return
    h = dp[D_PERIOD]
    ds[DS_IN_CUT] += h
    ds[DS_CUT_S] += h
    if ds[DS_IN_CUT] < dp[D_LAG_SETTLE]:
        return
    lam = dp[D_FORGET]
    running = ds[DS_STEP] != 0.0
    if not running:
        ds[DS_COUNT_RUN] = ds[DS_COUNT]
    ds[DS_COUNT] = lam * ds[DS_COUNT] + 1.0
    ds[DS_S1] = lam * ds[DS_S1] + 1.0
    ds[DS_SF] = lam * ds[DS_SF] + force
    ds[DS_SFF] = lam * ds[DS_SFF] + force * force
    t = ds[DS_IN_CUT]
    q = dp[D_POLE] ** (t / h)   # the process lag's decay since the segment's start
    ds[DS_SQ] = lam * ds[DS_SQ] + q
    ds[DS_SQQ] = lam * ds[DS_SQQ] + q * q
    ds[DS_SQF] = lam * ds[DS_SQF] + q * force
    # the process is read on the identified member, or on the one the feed test named
    ref = int(ds[DS_F_NAMED])
    if t >= dp[D_SETTLE]:   # the level: once the process's transient is over
        y0 = ds[DS_MODELS + ref * S_FIELDS + Y]
        ds[DS_L1] = lam * ds[DS_L1] + 1.0
        ds[DS_LF] = lam * ds[DS_LF] + force
        ds[DS_LFF] = lam * ds[DS_LFF] + force * force
        ds[DS_LY] = lam * ds[DS_LY] + y0
        ds[DS_LYY] = lam * ds[DS_LYY] + y0 * y0
        ds[DS_LYF] = lam * ds[DS_LYF] + y0 * force
    for m in range(N_MODELS):
        at = DS_MODELS + m * S_FIELDS
        if not running:   # where a step's run would begin (_stepped)
            ds[at + RUN_SSE], ds[at + RUN_RR], ds[at + RUN_R1] = (
                ds[at + SSE], ds[at + SRR], ds[at + SR1])
        ds[at + CARRY] *= lam
        y = ds[at + Y]
        u = t * y
        ds[at + SY] = lam * ds[at + SY] + y
        ds[at + SYY] = lam * ds[at + SYY] + y * y
        ds[at + SYF] = lam * ds[at + SYF] + y * force
        ds[at + SU] = lam * ds[at + SU] + u
        ds[at + SUU] = lam * ds[at + SUU] + u * u
        ds[at + SUY] = lam * ds[at + SUY] + u * y
        ds[at + SUF] = lam * ds[at + SUF] + u * force
        ds[at + SQY] = lam * ds[at + SQY] + q * y
        ds[at + SQU] = lam * ds[at + SQU] + q * u
        # the member's residual now, for its lag-one autocorrelation
        k, r, c, e, sse = _fit(ds, m)
        ds[at + SSE] = sse   # the tests below read it
        residual = force - k * y - r * u - c - e * q if math.isfinite(sse) else 0.0
        ds[at + SRR] = lam * ds[at + SRR] + residual * residual
        ds[at + SR1] = lam * ds[at + SR1] + residual * ds[at + RPREV]
        ds[at + RPREV] = residual
    full = (1.0 - math.exp(-1.0)) / (1.0 - lam)   # a window's worth of the cut
    if ds[DS_COUNT] < full:
        return
    threshold = dp[D_SIGMAS] * dp[D_SIGMAS]
    sse0 = _window_sse(ds, ref)
    best, best_sse = ref, sse0
    # Where the DAQ gives the axis feed, the feed test names the lag (it measures what the
    # force only implies); the force's lag test is for a machine without one (ref is 0).
    if ds[DS_F_SEEN] == 0.0:
        best, best_sse = _best(dp, ds, False)
    if _stepped(ds, best, best_sse):
        _unstep(ds, lam, STEP_PERIODS)
        return
    cause, size, std, alt = NONE, 0.0, 0.0, 0.0
    if best != ref and (_effective(ds, best, ds[DS_COUNT]) * math.log(sse0 / best_sse)
                        > threshold):
        row = D_MODELS + best * M_FIELDS
        cause, size = int(dp[row + M_CAUSE]), dp[row + M_SIZE]
        # half the bank's step either way
        std = 0.5 * h if cause == DEAD_TIME else 0.5 * (SERVO_RATIO - 1.0) * size
    else:
        # on the identified member: no lag drift found
        # the job's start, where the depth is known, or anywhere in the job's depths
        start = ds[DS_CUT_S] <= dp[D_FIRST_S]
        if ds[DS_L1] < full:   # the segment's level: once it holds a window's worth
            return
        level = _level(dp, ds, ref, _effective(ds, ref, ds[DS_L1]),
                       dp[D_K_FIRST_LO] if start else dp[D_K_LO],
                       dp[D_K_FIRST_HI] if start else dp[D_K_HI])
        if level[0] != NONE and level[3] > threshold:
            cause, size, std, alt = int(level[0]), level[1], level[2], level[4]
            if alt != 0.0 and int(ds[DS_CAUSE]) == GAIN + FRICTION - cause:
                # undecided between the two: the attribution standing stays
                cause, size, std, alt = GAIN + FRICTION - cause, alt, level[5], size
            if (cause == GAIN and not start and int(ds[DS_ALARM]) == GAIN
                    and size * ds[DS_ALARM_SIZE] > 0.0
                    and abs(size) < abs(ds[DS_ALARM_SIZE])):
                # away from the start a gain is read against the nearest end of the job's
                # depths: a bound on the drift (a 3 mm cut 40 % harder read against the
                # 3 mm end, a 2.5 mm one as 17 %), and the larger bound stands
                size = ds[DS_ALARM_SIZE]
    standing = int(ds[DS_CAUSE])
    levels = cause in (GAIN, FRICTION) and standing in (GAIN, FRICTION)
    if cause == NONE or (cause != standing and not levels):
        # a lapse shorter than the process's own transient (the force falling as the tool
        # leaves the work, or at a depth step, which no model of the feed follows) pauses
        # the cause standing; a longer one ends it. A cause found all through the lapse
        # stands from its first finding, not from the lapse's end (DS_NEXT).
        found = int(ds[DS_NEXT])
        same = found == cause or (cause in (GAIN, FRICTION) and found in (GAIN, FRICTION))
        ds[DS_NEXT_SINCE] = 0.0 if cause == NONE else (ds[DS_NEXT_SINCE] if same else 0.0) + h
        ds[DS_NEXT] = cause
        if standing != NONE and ds[DS_LAPSE] + h < dp[D_SETTLE]:
            ds[DS_LAPSE] += h
            return
        ds[DS_CAUSE], ds[DS_LAPSE] = cause, 0.0
        ds[DS_SINCE] = pymax(ds[DS_NEXT_SINCE] - h, 0.0)
        ds[DS_NEXT], ds[DS_NEXT_SINCE] = NONE, 0.0
        return
    ds[DS_NEXT], ds[DS_NEXT_SINCE], ds[DS_LAPSE] = NONE, 0.0, 0.0
    # a level drift stands while its attribution to gain or friction changes: the alarm
    # names the one that explains the window best now
    ds[DS_CAUSE], ds[DS_SIZE] = cause, size
    ds[DS_SINCE] += h
    if ds[DS_SINCE] >= dp[D_MEMORY]:
        _raise(ds, cause, size, std, alt)
        if cause == FRICTION and (dp[D_CORRECT] == 2.0 or (dp[D_CORRECT] == 1.0 and alt == 0.0)):
            _correct(dp, ds, size)


@compiled
def _correct(dp: np.ndarray, ds: np.ndarray, size: float) -> None:
    """The friction read in the cut, ``size`` of the identified friction's share of the force
    more than the estimator subtracts: the estimator is to take that off its estimate
    (:func:`drift_correction`), as an air move's re-zero would. The segment saw the estimate
    before it: another starts (LAG_SETTLE), and the cause
    standing starts afresh; the alarm holds. A friction left over (the window's feed is not the
    cut's next one) is read and corrected again a window later."""
    ds[DS_CORRECT] += size * dp[D_FRICTION]
    _segment(ds)
    ds[DS_SINCE] = 0.0


@compiled
def drift_correction(ds: np.ndarray) -> float:
    """The friction [N] the monitor has asked the estimator to take off its estimate since
    the last call (0: none; negative: to add), and the request cleared."""
    offset: float = ds[DS_CORRECT]
    ds[DS_CORRECT] = 0.0
    return offset


@compiled
def _raise(ds: np.ndarray, cause: int, size: float, std: float, alt: float) -> None:
    """The alarm says ``cause`` by ``size`` (counted where the cause is new)."""
    if int(ds[DS_ALARM]) != cause:
        ds[DS_ALARMS] += 1.0
    ds[DS_ALARM], ds[DS_ALARM_SIZE], ds[DS_ALARM_STD], ds[DS_ALARM_ALT] = cause, size, std, alt


@compiled
def drift_rezeroed(dp: np.ndarray, ds: np.ndarray, scale: float) -> None:
    """The estimator re-zeroed the friction in air: it now takes ``scale`` times the
    identified friction (the curve ``identify`` wrote, at scale 1). That is a measurement
    of the friction itself, no model's inference: beyond ``drift_sigmas`` standard deviations
    of the identified friction it is the friction drift, named once the reading has stood
    beyond them for REZERO_STAND_S and sized by it (the scale converges through the air move
    from the one before: a drift's reading, once beyond, stays beyond). Within them it is
    none, once the reading is over (:func:`_read`): a level in the cut named friction before
    (a cut at one depth and feed cannot tell it from a gain) was the process gain."""
    if dp[D_ON] == 0.0 or not (dp[D_FRICTION] > 0.0 and math.isfinite(scale)):
        return
    ds[DS_REZEROED], ds[DS_SCALE] = REZ_READING, scale
    size, std = scale - 1.0, pymax(dp[D_FRICTION_STD], REZERO_STD)
    if abs(size) <= dp[D_SIGMAS] * std:
        ds[DS_BEYOND] = 0.0
        return
    ds[DS_BEYOND] += dp[D_PERIOD]
    if ds[DS_BEYOND] >= REZERO_STAND_S - 1e-9:
        _raise(ds, FRICTION, size, std, 0.0)


@compiled
def _read(dp: np.ndarray, ds: np.ndarray) -> None:
    """The re-zero's reading is over (a control period passed without one: the tool left
    the air, or the estimator stopped reading): the last scale stands. Within
    ``drift_sigmas`` of the identified friction, a level named friction with a gain beside it
    was the gain."""
    ds[DS_REZEROED], ds[DS_BEYOND] = REZ_READ, 0.0
    std = pymax(dp[D_FRICTION_STD], REZERO_STD)
    if (abs(ds[DS_SCALE] - 1.0) <= dp[D_SIGMAS] * std and int(ds[DS_ALARM]) == FRICTION
            and ds[DS_ALARM_ALT] != 0.0):
        _raise(ds, GAIN, ds[DS_ALARM_ALT], dp[D_K_STD], 0.0)


@compiled
def drift_tool(ds: np.ndarray) -> None:
    """Another tool: another identified model, watched afresh (the bank restarts, the alarm
    ends, the job's start is the new tool's); the count of alarms and the override applied
    stay."""
    applied, alarms = ds[DS_APPLIED], ds[DS_ALARMS]
    ds[:] = 0.0
    ds[DS_APPLIED], ds[DS_ALARMS] = applied, alarms


def alarm(ds: FloatArray) -> tuple[int, float, float, float]:
    """The alarm in the monitor's state: cause, size, standard deviation, the other reading of
    a level (:func:`drift_text` takes them)."""
    return (int(ds[DS_ALARM]), float(ds[DS_ALARM_SIZE]), float(ds[DS_ALARM_STD]),
            float(ds[DS_ALARM_ALT]))


def adopted(ds: FloatArray) -> tuple[int, float]:
    """The lag drift the law took into its model (``drift_adopt_model``): cause (NONE: none)
    and size, as the alarm named them (:func:`drift_text` takes them)."""
    return int(ds[DS_ADOPTED]), float(ds[DS_ADOPTED_SIZE])


def drift_text(c: ControllerBase, cause: int, size: float, std: float, alt: float = 0.0,
               adopted: tuple[int, float] = (NONE, 0.0)) -> str:
    """The alarm in words: what drifted, identified and now, what the law did with it
    (``adopted``: the lag drift it took into its model, :func:`adopted`) and what to do
    (``alt``: the other reading of a level, where the cut cannot tell a gain from a friction
    drift)."""
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
    taken = adopted_text(c, *adopted)
    return f'{what}{"; " if taken else ""}{taken}: re-commission (identify this session)'


def adopted_text(c: ControllerBase, cause: int, size: float) -> str:
    """The model the law predicts with, where it took a lag drift into it (:func:`adopted`;
    '' where it did not: the commissioned model)."""
    if cause == DEAD_TIME:
        return (f'the {c.controller} law predicts with {(c.model_dead_time_s + size) * 1e3:.0f} '
                'ms of dead time until the tool changes')
    if cause == SERVO:
        return f'the {c.controller} law predicts with the servo x{size:.2f} until the tool changes'
    return ''
