"""What a control law is: the settings every law shares, the compiled arrays a law reads and
writes, and the :class:`Law` a law's module declares.

A law is one module (in :mod:`turning_force.core.control.laws`, or in a package of its own that
names it under the ``turning_force.laws`` entry point group). It holds:

- ``Settings``: a frozen dataclass subclass of :class:`ControllerBase` with the law's own
  fields, each made by :func:`~turning_force.core.settings.setting` (they become
  ``force_controller`` parameters, prefixed with the law's name by convention), and its
  ``check`` (call ``super().check()`` first);
- ``fill(settings) -> (parameters, state_size)``: the law's parameters in the order its
  compiled code reads them from ``C_LAW`` on, and how many state slots it uses from ``CS_LAW``
  on;
- compiled functions (:func:`~turning_force.core.compiled.compiled`), found by name:
  ``step(cp, cs, force, rate, out)`` writes the request into ``out[OUT_PCT]``, the error into
  ``out[OUT_ERR]`` and the sliding variable (0 if none) into ``out[OUT_S]``; ``reset(cp, cs)``
  the fresh state of a new cut from the held request ``cs[CS_HELD]``; optionally
  ``finite(cp, cs) -> bool`` (whether the state is fit to go on: the guard resets the law
  otherwise), ``sent(cp, cs, level)`` (the PMC level sent, once the quantiser chose it) and
  ``adopt(cp, cs, cause, size) -> bool`` (the drift monitor named a lag drift, a member of its
  bank, :mod:`.drift`: whether the law took it into its model, as :mod:`.laws.mpc` and the
  Smith predictor of :mod:`.laws.smc` do; cause ``drift.NONE``: back to the commissioned
  model, at a tool change, before ``reset``);
- ``LAW = Law(name, Settings, fill, summary)`` (``closed_loop=False`` for a law that ignores
  the force: the oscillation alarm does not watch it).

What every law shares runs around ``step`` (:mod:`.update`): the guard on non-finite input,
output and state, the error-feedback quantiser, the reachability flag.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import numpy.typing as npt

from turning_force.core import shared
from turning_force.core.compiled import Arr, compiled, entry, pymax, pymin
from turning_force.core.control import drift
from turning_force.core.pmc.overrides import get_table, override_table
from turning_force.core.settings import Settings, setting

__all__ = [
    'CS_HELD',
    'CS_LAW',
    'C_LAW',
    'C_RPM',
    'OUT_ERR',
    'OUT_PCT',
    'OUT_S',
    'ControlOutput',
    'ControllerBase',
    'Law',
    'clip',
    'feed_rate',
    'pct',
    'set_spindle_speed',
    'spindle_speed',
]

FloatArray = npt.NDArray[np.float64]

# --- the compiled arrays ----------------------------------------------------------------------
# Parameters every law has (cp); a law's own follow from C_LAW.
C_KIND, C_REF, C_PERIOD, C_MIN, C_MAX, C_GAP, C_EF, C_UNREACH, C_FEED_RATE, C_CONT = range(10)
C_OSC_SWING, C_OSC_COUNT, C_OSC_REACTION = range(10, 13)   # the oscillation alarm (.update)
# The spindle: the programmed feed [mm/rev], the spindle_speed_rpm parameter, the speed in use
# (the live one, machine/spindle_speed, where it is given: :func:`spindle_speed`).
C_FEED_REV, C_RPM_SET, C_RPM = range(13, 16)
# The feed exponent g the laws assume (model_cutting_exponent): the oscillation reaction's
# feed-forward of a depth step (.update._feed_forward).
C_EXPONENT = 16
# The half-period at which the identified model (model_*: dead time, servo, tau_c) would cycle,
# pi / w_u with its phase -180 degrees at w_u, 0 where it never gets there: the oscillation
# reaction's least half-period (.update._alarm; :func:`model_half_period_s`).
C_MODEL_HALF = 17
# The process lag tau_c the laws assume (model_cutting_time_constant_s): where a fall of the
# force heads (.update._fall).
C_TAU_C = 18
C_DRIFT = 19   # the drift monitor's parameters (.drift), drift.PARAMS of them
C_LAW = C_DRIFT + drift.PARAMS
# State every law has (cs): the request held, the quantiser's carry, the time pinned at an end
# of the table and which end, the resets; whether the tool is in the cut (the last override
# applied said so); the oscillation detector's (.update): the direction of the error's current
# swing (1 rising, -1 falling, 0 not started), its extreme so far, the turning point before,
# the last swing, the swings counted, the time since the last turn, the alarm (1 while it
# holds), the alarms raised, the level the reaction holds (the detune
# reaction's integral), the counted swings' half-periods' sum, the detune reaction's
# crossover, whether it waits for the force to settle (1) after the gate set the feed, and
# whether the last swing was larger than the one before (1: a kick's return, .update._turn),
# the log of the force's share of the reference the detune reaction saw last period, the swing
# before the last, whether the last two swings are the loop's own (1) or the last is the
# third after a kick (0: the one before it was the kick's), and whether the loop is open (1:
# the PMC applied a level the law did not ask for, .update.controller_applied), the alarmed
# cycle's mean half-period, the time since the detune reaction's excursion came back under
# its upper bound (-1: none timed, .update._quicken) and that excursion's sign, the level sent
# summed over the swing under way and over the cycle counted (from the third swing after a
# kick), and the cycle's time; the error's mean while the request is pinned at an end
# (.update._track_reach).
CS_HELD, CS_CARRY, CS_PINNED, CS_RESETS, CS_SIDE, CS_ENGAGED = range(6)
(CS_O_DIR, CS_O_EXT, CS_O_LAST, CS_O_SWING, CS_O_COUNT, CS_O_SINCE, CS_O_ALARM, CS_O_ALARMS,
 CS_O_HOLD, CS_O_HALVES, CS_O_CROSSOVER, CS_O_WAIT, CS_O_GREW,
 CS_O_LOG_FORCE, CS_O_SWING_BEFORE, CS_O_PAIRED, CS_O_OPEN, CS_O_HALF, CS_O_TAIL,
 CS_O_TAIL_SIGN, CS_O_HSUM, CS_O_CSUM, CS_O_CTIME) = range(6, 29)
CS_PIN_ERROR = 29
# The detune reaction's answer to a depth step (.update._feed_forward): its phase (0
# watching, 1 answering a step), the time in the phase (watching: calm so far), the level and
# the log force share the step started from, and the two lags that predict the force's
# answer to the level's moves since.
CS_O_FF_PHASE, CS_O_FF_TIME, CS_O_FF_LEVEL, CS_O_FF_SHARE, CS_O_FF_NEAR, CS_O_FF_FAR = \
    range(30, 36)
# The detune reaction's ceiling on its crossover (.update._quicken; lowered where the
# reaction's own loop cycled slowly: .update._recycle), and the time since the alarm (before
# an alarm, negative while the detector lets a law's switch to an adopted model settle:
# .update.ADOPT_SETTLE).
CS_O_TOP, CS_O_AGE = 36, 37
# The oscillation detector's last two swings' half-periods (.update._turn: a limit cycle's
# swings of one direction keep their pace), and the swing under way's calm (.update._watch):
# the error where it last got on by the hysteresis, when (the time since the turn), and its
# longest stall so far.
CS_O_HALF_LAST, CS_O_HALF_BEFORE, CS_O_MARK, CS_O_MARK_AT, CS_O_STALL = range(38, 43)
# 1 where the detector's count began at a kick's rise out of a calm spell (.update.ONSET_RING);
# the swing under way and the spells out of the cut or with the loop open (1 in one, 2 once the
# detector watches again, 0 none since the last turn), and the extreme the force reached in
# the last, where the swing ends at a later turn (NaN: none) (.update._reopen).
CS_O_ONSET, CS_O_REOPEN, CS_O_FLOOR = 43, 44, 45
# 1 after a turn the detector took for a wiggle of the noise (.update._turn), until the next;
# 1 where a swing of the detector's count held a spell with the loop open for another reason
# than the gate's air-cut and entry feeds (.update.OSC_SLOW_HALF_S).
CS_O_WIGGLE, CS_O_SPELLED = 46, 47
# The axis feed the DAQ measured over the last block, a share of the 100 % override's feed
# (NaN: none measured), the level the loop applied over about the last second (the
# detector's test of a spell's cause: .update.EXIT_FEED_SHARE).
CS_O_FEED, CS_O_LEVEL = 48, 49
# The time the swing under way spent in spells (the gate's air-cut and entry feeds, or the
# loop open), 1 where one of them had the loop open by another reason (the dial, a hold, a
# stand-down), and the last two swings' half-periods without their spells' time
# (.update.OSC_SLOW_HALF_S).
CS_O_SPELL_S, CS_O_OPENED, CS_O_NET_LAST, CS_O_NET_BEFORE = 50, 51, 52, 53
# The hold through the tool's exit where the gate has not seen it yet (.update._fall): 1 while
# it holds, the level it holds, the axis feed's mean while the force was at the reference (a
# level [%]; 0: not since the tool entered the cut), how long it has held (before: how long
# the fall has looked like the exit), how long the force has been calm in it, the entry feed
# the gate applied last (0: none yet), and the axis feed's recent mean (a share of the 100 %
# feed).
CS_FALL, CS_FALL_CAP, CS_FALL_BASE, CS_FALL_S, CS_FALL_CALM, CS_FALL_ENTRY, CS_FALL_FEED = \
    range(54, 61)
# 1 while the gate holds its entry feed with the tool in the cut, or the loop holds its level
# through an exit the gate has not seen (.update._fall), as of the last level applied: the law
# rests on that level while the force may still rise behind the cut's own lag, which a law with
# a model of it follows (.laws.mpc).
CS_ENTERING = 61
# The detune reaction's law on the axis feed the DAQ measured (.update._by_feed): the log of
# that feed's share of the 100 % feed, lagged as the force lags the feed
# (.update.REACTION_LAG_S), 1 while the law runs on it (0: the PI law on the level sent, where
# no feed is measured or it was lost), the cut's own log force share it reads (NaN: none
# yet), and that reading's lag [s] (0: none; set where the law cycled: .update.FEED_CYCLE_RATIO).
CS_O_MODEL_FEED, CS_O_BY_FEED, CS_O_CUT, CS_O_CUT_S = 62, 63, 64, 65
CS_DRIFT = 66   # the drift monitor's state (.drift), drift.STATE values
CS_LAW = CS_DRIFT + drift.STATE
# One period's output: request, error, sliding variable, reachable, oscillation alarm, the
# drift alarm (what drifted: drift.CAUSES' index, 0 none) and the drift's size.
OUT_PCT, OUT_ERR, OUT_S, OUT_REACH, OUT_OSC, OUT_DRIFT, OUT_DRIFT_SIZE = range(7)
OUT_SIZE = 7
# What the oscillation alarm does (oscillation_reaction).
OSCILLATION_REACTIONS = ('detune', 'hold_mean', 'programmed_feed', 'none')


@compiled
def spindle_speed(cp: np.ndarray, rpm: float) -> None:
    """The spindle speed every law uses from now on [rpm]: the live one (machine/spindle_speed;
    under constant surface speed, G96, it changes through a cut), or where that is not given
    (NaN) or not above 0, the ``spindle_speed_rpm`` parameter. The feed rate of the 100 %
    override (``C_FEED_RATE``, :func:`pct`, :func:`feed_rate`) follows it."""
    if not (rpm > 0.0 and math.isfinite(rpm)):
        rpm = cp[C_RPM_SET]
    cp[C_RPM] = rpm
    cp[C_FEED_RATE] = cp[C_FEED_REV] * rpm


@entry('void(float64[::1], float64)')
def set_spindle_speed(cp: Arr, rpm: float) -> None:
    """:func:`spindle_speed` from Python (the controller node)."""
    spindle_speed(cp, rpm)


def model_half_period_s(c: ControllerBase) -> float:
    """pi / w_u of the model the laws assume: w_u where the phase of exp(-L s) over the servo
    (first or second order, Park Eq. 2, Hwang & Chen Eq. 1) and the cut's lag tau_c (Park Eq. 1)
    reaches -180 degrees, found by bisection below the loop's Nyquist rate; 0 where it does not
    get there (the default model, no dead time and two first-order lags)."""

    def phase(w: float) -> float:
        if c.model_servo_model == 'first_order':
            servo = math.atan(w * c.model_servo_time_constant_s)
        else:
            r = w / c.model_servo_natural_freq_rad_s
            servo = math.atan2(2.0 * c.model_servo_damping * r, 1.0 - r * r)
        return w * c.model_dead_time_s + servo + math.atan(w * c.model_cutting_time_constant_s)

    low, high = 0.0, c.nyquist_rad_s
    if phase(high) < math.pi:
        return 0.0
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if phase(middle) < math.pi else (low, middle)
    return math.pi / high


@compiled
def clip(cp: np.ndarray, pct: float) -> float:
    """A request inside the override table's range."""
    return pymin(pymax(pct, cp[C_MIN]), cp[C_MAX])


@compiled
def pct(cp: np.ndarray, rate_mm_min: float) -> float:
    """A feed rate [mm/min] as an override of the programmed feed [%]."""
    return 100.0 * rate_mm_min / cp[C_FEED_RATE]


@compiled
def feed_rate(cp: np.ndarray, override_pct: float) -> float:
    """An override [%] as a feed rate [mm/min]."""
    return override_pct / 100.0 * cp[C_FEED_RATE]


@compiled
def heading(cp: np.ndarray, force: float, rate: float) -> float:
    """Where the force heads: ``F + tau_c dF/dt``, the asymptote of the first-order process
    lag the laws assume (Park Eq. 1, ``C_TAU_C``), the force's rate being the estimate's."""
    return force + cp[C_TAU_C] * rate


@dataclass(frozen=True)
class ControllerBase(Settings):
    """The force controller's settings every law shares (``force_controller`` parameters).

    The settings the node and the files use, :class:`~.settings.ControllerSettings`, are these
    with every law's own (each law's ``Settings`` derives from this class)."""

    SECTION = 'force_controller'

    controller: str = setting('smc', 'Control law')
    reference_force_n: float = setting(500.0, 'Reference cutting force F_ref; below '
                                       'max_feed_force_n', 'N', low=0.0, low_open=True,
                                       high=1e5, dynamic=True, cite='Park 1998, Eq. 9')
    control_period_s: float = shared.control_period_s()
    spindle_speed_rpm: float = shared.spindle_speed_rpm()
    spindle_speed_stale_s: float = shared.spindle_speed_stale_s()
    programmed_feed_mm_rev: float = shared.programmed_feed_mm_rev()
    override_table: str = override_table()
    max_feed_force_n: float = shared.max_feed_force_n()
    tools_file: str = shared.tools_file()
    quantiser: str = setting('error_feedback', 'How a request becomes a PMC level: the '
                             "bridge's nearest level, or error feedback (noise shaping: the "
                             'levels sent average to the request); the oscillation reaction '
                             'sends its requests with error feedback always',
                             choices=('nearest', 'error_feedback'))
    unreachable_after_s: float = setting(1.0, 'A request held at the end of the table this long '
                                         '(150 % with the force below the reference, 0 % with '
                                         'it above) reports the reference unreachable', 's',
                                         low=0.0, low_open=True, high=3600.0, dynamic=True)
    initial_override_pct: float = setting(100.0, 'Override before the first update', '%',
                                          low=0.0, high=255.0)
    model_servo_time_constant_s: float = setting(0.17, 'Servo time constant tau_s the '
                                                 'controllers assume (Park Eq. 2)', 's', low=0.0,
                                                 low_open=True, high=10.0, cite='Park 1998, Eq. 2')
    model_servo_model: str = setting('first_order', 'Servo model the predictor assumes: first '
                                     'order (tau_s, Park Eq. 2) or second order (w_n, damping, '
                                     'Hwang & Chen Eq. 1)', choices=('first_order',
                                                                     'second_order'))
    model_servo_natural_freq_rad_s: float = setting(60.0, 'Second-order servo natural frequency '
                                                    'the predictor assumes', 'rad/s', low=0.0,
                                                    low_open=True, high=1e4,
                                                    cite='Hwang & Chen 1990, Eq. 1')
    model_servo_damping: float = setting(0.7, 'Second-order servo damping the predictor assumes',
                                         low=0.0, low_open=True, high=10.0,
                                         unit='-', cite='Hwang & Chen 1990, Eq. 1')
    model_dead_time_s: float = setting(0.0, 'PMC dead time the predictor assumes (Kim: 0.08 s '
                                       'on a FANUC); from `turning-force identify`', 's', low=0.0,
                                       high=2.0, cite='Kim, Eqs. 1-2')
    model_cutting_time_constant_s: float = setting(0.05, 'Process time constant tau_c the laws '
                                                   'assume (Park Eq. 1): the models of the SMC '
                                                   'and the predictive law, and where a fall '
                                                   'of the force heads (the hold through an '
                                                   'exit the gate has not seen)', 's', low=0.0,
                                                   low_open=True, high=10.0,
                                                   cite='Park 1998, Eq. 1')
    model_cutting_exponent: float = setting(1.0, 'Feed exponent g of the force the laws assume, '
                                            'F = K_s d f^g (Kienzle; 1: Park)', low=0.1,
                                            high=2.0, unit='-', cite='Hwang & Chen 1990, Eq. 3')
    oscillation_swing_n: float = setting(
        50.0, 'Oscillation alarm: a swing of the force error (from one turning point to the '
        'next) this large counts toward it (50 N: the peak to peak issue 16 calls an '
        'oscillation; 40 N alarmed a commissioned loop ringing 48-51 N after a depth step, '
        'and its reaction left it 12 N off); 0: no alarm', 'N', low=0.0, high=1e5, dynamic=True,
        cite='Astrom & Hagglund 1984 (a limit cycle as a relay experiment)')
    oscillation_swings: int = setting(
        4, 'Oscillation alarm: this many counted swings in a row raise it, each 0.07-2 s after '
        'the one before (noise turns faster) and no smaller than 0.7 of it, or with it no '
        'smaller than 0.7 of the two before (a drifting mean makes every other swing small); '
        'the third after a rise and a return at least 0.7 of it (a depth step or an entry: '
        'its two swings) counts from 0.1 of the return (0.3 after a calm spell); from the '
        'fourth on, one no larger than '
        'the one two before keeps its pace (within 2.5 of its half-period); a swing out of a '
        'calm spell (stalled over half its time, or slower than 2 s) only starts a count; '
        'a slow cycle (0.35 s or more a swing) whose last three swings keep within 0.7 of '
        'each other and their pace raises it a swing early (at three swings at least)',
        '-', low=2, high=100, dynamic=True)
    oscillation_reaction: str = setting(
        'detune', 'What the oscillation alarm does until the run ends or the tool changes: '
        "where the DAQ measures the axis feed, the level from the cut's own force per feed "
        '(the force against the measured feed through 0.8 of model_cutting_exponent: a depth '
        "step answered at once, the servo's ring left alone), otherwise "
        "a slow PI law on the log of the feed whose crossover is a fifth of the oscillation's "
        'frequency, raised up to 1/3.5 of it where the force comes back slowly after a depth '
        'step, and a depth step down answered at once through the feed exponent '
        "model_cutting_exponent (detune), hold the alarmed cycle's mean override "
        '(hold_mean), ask for the programmed feed (programmed_feed), or nothing but the alarm '
        '(none)',
        choices=OSCILLATION_REACTIONS, dynamic=True)
    # The drift monitor (.drift): the identified model above and its uncertainties, which
    # `turning-force identify` writes.
    drift_monitor: bool = setting(
        False, 'Drift monitor: compare the estimated force in the cut with what the identified '
        'model (model_*, drift_*) predicts from the override applied, and say what drifted '
        '(PMC dead time, servo, process gain, friction) and by how much; identify turns it on')
    drift_sigmas: float = setting(
        4.0, 'Drift monitor: how many standard deviations (of the identified values, and of '
        "the monitor's own likelihood-ratio statistic) a difference must reach to be drift",
        '-', low=1.0, high=20.0, cite='Basseville & Nikiforov 1993, Sec. 4.2')
    drift_memory_s: float = setting(
        1.0, 'Drift monitor: the window it fits the model over, and how long a cause must '
        'stand before the alarm', 's', low=0.1, high=60.0)
    drift_ksd_min_n_mm: float = setting(
        0.0, "Drift monitor: the identified K_s d at the job's shallowest depth (the secant at "
        'the programmed feed, Park Eq. 7)', 'N/mm', low=0.0, high=1e7)
    drift_ksd_max_n_mm: float = setting(
        0.0, "Drift monitor: the identified K_s d at the job's deepest depth", 'N/mm', low=0.0,
        high=1e7)
    drift_ksd_std: float = setting(
        0.0, 'Drift monitor: relative standard deviation of a force the identified process '
        'model predicts (its parameters and its residual in the commissioning cut)', '-',
        low=0.0, high=1.0)
    drift_friction_n: float = setting(
        0.0, "Drift monitor: the identified friction current at the feed that holds the "
        "reference at the job's start, as force (Park Eqs. 25, 26): a friction drift's share "
        'of the estimate is measured against it',
        'N', low=0.0, high=1e5)
    drift_friction_std: float = setting(
        0.0, 'Drift monitor: relative standard deviation of the identified friction',
        '-', low=0.0, high=1.0)
    drift_friction_max_change: float = setting(
        0.5, 'Drift monitor: the largest friction change it names, relative (as the '
        "estimator's friction re-zero follows at most rezero_max_change); a larger offset is "
        'no friction drift', '-', low=0.0, high=10.0)
    drift_dead_time_std_s: float = setting(
        0.0, 'Drift monitor: standard deviation of the identified PMC dead time', 's', low=0.0,
        high=1.0)
    drift_servo_std: float = setting(
        0.0, "Drift monitor: relative standard deviation of the identified servo's time scale",
        '-', low=0.0, high=1.0)

    drift_first_s: float = setting(
        0.0, "Drift monitor: how long the job's start lasts, in the cut (until its first "
        'depth change): there the depth is known, and the force tells the process gain from a '
        'depth (drift_ksd_first_*); 0: no such start', 's', low=0.0, high=1e6)
    drift_ksd_first_min_n_mm: float = setting(
        0.0, "Drift monitor: the identified K_s d at the shallowest depth of the job's start",
        'N/mm', low=0.0, high=1e7)
    drift_ksd_first_max_n_mm: float = setting(
        0.0, "Drift monitor: the identified K_s d at the deepest depth of the job's start",
        'N/mm', low=0.0, high=1e7)
    drift_friction_correction: str = setting(
        'decided', 'Drift monitor: where it names a friction drift in the cut, the estimator '
        'takes it off its estimate at once, as an air move re-zeroes it (decided: where the '
        'window tells it from a process gain; named: also where it cannot, a cut at one depth '
        'and feed, where a gain drift of a few percent would be taken for friction and the '
        'force held that much above the reference until an air move; none: it only says so)',
        choices=drift.CORRECTIONS)
    drift_adopt_model: bool = setting(
        True, 'Drift monitor: where it names a PMC dead time or servo drift, a law that '
        "predicts with the machine's model (mpc; smc with smc_predictor, its design too) takes "
        'the named dead time and servo into its own model from then on, until the tool '
        'changes, and an oscillation alarm raised before lets go (the ring was the drifted '
        "loop's, the model taken its cure; the detector watches afresh); off: the alarm only "
        'says so')
    drift_feed_test: bool = setting(
        True, 'Drift monitor: a PMC dead time or servo drift is named from the axis feed the '
        'DAQ measures against the feed the identified model gives from the override applied '
        '(within 0.1-0.2 s of an override step, in air or in the cut); off: from the force '
        'alone, over drift_memory_s (a feed signal that does not come from the one the '
        'commissioning session identified the servo on)')

    def check(self) -> None:
        super().check()
        if self.drift_monitor and not 0.0 < self.drift_ksd_min_n_mm <= self.drift_ksd_max_n_mm:
            self.fail('drift_ksd_min_n_mm', 'the drift monitor needs 0 < drift_ksd_min_n_mm <= '
                      f'drift_ksd_max_n_mm ({self.drift_ksd_max_n_mm!r}): identify writes them')
        if (self.drift_monitor and self.drift_first_s > 0.0
                and not 0.0 < self.drift_ksd_first_min_n_mm <= self.drift_ksd_first_max_n_mm):
            self.fail('drift_ksd_first_min_n_mm', 'with drift_first_s the drift monitor needs '
                      '0 < drift_ksd_first_min_n_mm <= drift_ksd_first_max_n_mm '
                      f'({self.drift_ksd_first_max_n_mm!r}): identify writes them')
        table = get_table(self.override_table)
        if not table.min_pct <= self.initial_override_pct <= table.max_pct:
            self.fail('initial_override_pct', f'outside the {table.name} range '
                                              f'[{table.min_pct:g}, {table.max_pct:g}] %')
        if self.reference_force_n >= self.max_feed_force_n:
            self.fail('reference_force_n', f'not below max_feed_force_n '
                                           f'({self.max_feed_force_n:g} N)')

    @property
    def programmed_feed_rate_mm_min(self) -> float:
        return self.programmed_feed_mm_rev * self.spindle_speed_rpm

    @property
    def nyquist_rad_s(self) -> float:
        """The control loop's Nyquist rate, pi / control_period_s."""
        return math.pi / self.control_period_s


@dataclass(frozen=True)
class Law:
    """A control law as the controller runs it: its name, its settings, how it reads them into
    its compiled parameters (``fill``), and a line that says what it is. Its compiled
    functions are its module's ``step``, ``reset``, ``finite``, ``sent`` and ``adopt`` (see
    the module's text)."""

    name: str
    settings: type[ControllerBase]
    fill: Callable[[ControllerBase], tuple[Sequence[float], int]]
    summary: str
    # False for a law that ignores the force (a scripted excitation): it cannot close a limit
    # cycle, so the oscillation alarm does not watch it (its steps are no cycle).
    closed_loop: bool = True

    @property
    def module(self) -> ModuleType:
        """The module that declares the law (and holds its compiled functions)."""
        return sys.modules[self.settings.__module__]


@dataclass(frozen=True)
class ControlOutput:
    """One control decision (the core side of ``FeedCommand``).

    ``error_n`` is ``F - F_ref`` (Park Eq. 9); ``sliding_variable`` is the controller's ``s``
    (0 for controllers that have none); ``reachable`` is false once the request has sat at the
    table's end, pushing the wrong way for the force to follow, for ``unreachable_after_s``: at
    150 % with the force still below the reference (the cut is too light for it), or at 0 %
    with it still above.
    """

    override_pct: float
    error_n: float
    sliding_variable: float
    reachable: bool = True
    oscillating: bool = False   # the oscillation alarm (.update.controller_update) holds
    drift: int = 0              # the drift alarm: what drifted (.drift.CAUSES' index), 0 none
    drift_size: float = 0.0     # by how much (relative; seconds for the dead time)
