"""One control period, compiled, for every law: the law's ``step`` and what every law shares
around it (:class:`~turning_force.core.control.base.Controller` states it): the guard on
non-finite input, output and state, the error-feedback quantiser, the reachability flag, the
oscillation alarm and its reaction, the hold through the tool's exit where the gate has not
seen it yet (:func:`controller_update`), and the anti-windup on the override the PMC applied
(:func:`controller_applied`).

The law is chosen by its number (``C_KIND``) through the dispatch
:mod:`turning_force.core.control.dispatch` writes for the laws installed.
:class:`~turning_force.core.control.base.Controller` runs :func:`controller_update` one period
at a time, the compiled loops (:mod:`turning_force.core.kernel.loops`) many periods at once.
"""

from __future__ import annotations

import math

import numpy as np

from turning_force.core.compiled import Arr, compiled, entry, pymax, pymin, quantise, table_row
from turning_force.core.control import dispatch
from turning_force.core.control.drift import (
    D_ADOPT,
    D_MEMORY,
    DEAD_TIME,
    DS_ADOPTED,
    DS_ADOPTED_SIZE,
    DS_ALARM,
    DS_ALARM_SIZE,
    NONE,
    SERVO,
    drift_applied,
    drift_feed,
    drift_rezeroed,
    drift_step,
    drift_tool,
)
from turning_force.core.control.law import (
    C_CONT,
    C_DRIFT,
    C_EF,
    C_EXPONENT,
    C_FEED_RATE,
    C_GAP,
    C_KIND,
    C_LAW,
    C_MAX,
    C_MIN,
    C_MODEL_HALF,
    C_OSC_COUNT,
    C_OSC_REACTION,
    C_OSC_SWING,
    C_PERIOD,
    C_REF,
    C_RPM,
    C_UNREACH,
    CS_CARRY,
    CS_DRIFT,
    CS_ENGAGED,
    CS_ENTERING,
    CS_FALL,
    CS_FALL_BASE,
    CS_FALL_CALM,
    CS_FALL_CAP,
    CS_FALL_ENTRY,
    CS_FALL_FEED,
    CS_FALL_S,
    CS_HELD,
    CS_LAW,
    CS_O_AGE,
    CS_O_ALARM,
    CS_O_ALARMS,
    CS_O_BY_FEED,
    CS_O_COUNT,
    CS_O_CROSSOVER,
    CS_O_CSUM,
    CS_O_CTIME,
    CS_O_CUT,
    CS_O_CUT_S,
    CS_O_DIR,
    CS_O_EXT,
    CS_O_FEED,
    CS_O_FF_FAR,
    CS_O_FF_LEVEL,
    CS_O_FF_NEAR,
    CS_O_FF_PHASE,
    CS_O_FF_SHARE,
    CS_O_FF_TIME,
    CS_O_FLOOR,
    CS_O_GREW,
    CS_O_HALF,
    CS_O_HALF_BEFORE,
    CS_O_HALF_LAST,
    CS_O_HALVES,
    CS_O_HOLD,
    CS_O_HSUM,
    CS_O_LAST,
    CS_O_LEVEL,
    CS_O_LOG_FORCE,
    CS_O_MARK,
    CS_O_MARK_AT,
    CS_O_MODEL_FEED,
    CS_O_NET_BEFORE,
    CS_O_NET_LAST,
    CS_O_ONSET,
    CS_O_OPEN,
    CS_O_OPENED,
    CS_O_PAIRED,
    CS_O_REOPEN,
    CS_O_SINCE,
    CS_O_SPELL_S,
    CS_O_SPELLED,
    CS_O_STALL,
    CS_O_SWING,
    CS_O_SWING_BEFORE,
    CS_O_TAIL,
    CS_O_TAIL_SIGN,
    CS_O_TOP,
    CS_O_WAIT,
    CS_O_WIGGLE,
    CS_PIN_ERROR,
    CS_PINNED,
    CS_RESETS,
    CS_SIDE,
    OUT_DRIFT,
    OUT_DRIFT_SIZE,
    OUT_ERR,
    OUT_OSC,
    OUT_PCT,
    OUT_REACH,
    OUT_S,
    clip,
    spindle_speed,
)
from turning_force.core.control.law import heading as force_heading

__all__ = ['control_applied', 'control_feed', 'control_rezeroed', 'control_step', 'control_tool',
           'controller_applied', 'controller_feed',
           'controller_rezeroed', 'controller_start', 'controller_tool', 'controller_update']

# FeedOverride.REASON_NORMAL: the controller's request went through as asked; REASON_RISE_LIMIT
# and REASON_FEED_FLOOR: it went through limited (its rise, its floor), the loop still closed.
# Under any other reason the PMC holds a level of its own (the dial, a hold, the entry feed, a
# stand-down for threading): the loop is open, and the force's swings there are the program's
# (a depth step, the threading pass), no limit cycle, which the detector does not watch.
REASON_NORMAL, REASON_RISE_LIMIT, REASON_FEED_FLOOR = 0, 9, 10
REASON_AIR_CUT = 7   # the gate's air-cut and entry feeds: the tool out of the cut or entering
# Reachability: the error's mean that says the force reached the reference, over this long (a
# third of unreachable_after_s's default: a reference that comes within reach, a deeper cut,
# un-flags in a few tenths of a second).
REACH_MEAN_S = 0.3
# The oscillation detector: a turning point is where the error has come back this fraction of
# the alarm's swing from its extreme (hysteresis against noise); a counted swing comes
# HALF_MIN_S to HALF_MAX_S after the one before (noise turns faster; slower is no cycle: the
# fastest loops of the generated population, no dead time and a 0.1 s servo, cycle at 0.07 s a
# half) and does not die away (a transient's swings do, a limit cycle's do not): it is at least
# DECAY of the one before, or with it at least DECAY of the two before. A swing runs from one
# extreme to the next, so a mean level that drifts under the cycle (a depth step's transient
# still settling) adds to every other swing and takes from the others: one of a growing cycle
# measured 0.69 of the one before it (once alarmed 2.05 s after the onset); two swings
# together, a period's peak to peak, carry no drift. After a kick (a depth step or an entry: a
# rise, then a return at least DECAY of it), the third swing counts whatever its size: the
# kick, not the loop, made the two before it large (a 3.5 mm step's return was 705 N, the
# cycle's swings 175 N: once alarmed 2.46 s after the onset; a x3.5 step's rise of 880 N and
# return of 793 N, then a cycle that grew from 117 N to 340 N: alarmed 2.44 s after the onset
# while the kick had to be a return larger than its rise), and the fourth is held to DECAY of
# the third. A linear loop's transient swings shrink by the same ratio from the third on (that
# step's third was 0.15 of its return), so the fourth swing still tells a transient from a
# cycle. A swing under the alarm's swing and faster than OSC_HALF_MIN_S is a wiggle of the
# noise at an extreme, no swing at all: the swing before it goes on to the further of the
# wiggle's two turns, and its turn, count and half-period stand (a noisy drive's cycle of
# 200-255 N, its troughs wiggling by 17-20 N within 0.03 s, started its count afresh at every
# trough: bench_loop_watch seed 101's #41, alarmed 2.05 s after the onset; 1.68 s now).
OSC_HYSTERESIS, OSC_DECAY = 1.0 / 3.0, 0.7
OSC_HALF_MIN_S, OSC_HALF_MAX_S = 0.07, 2.0
# A limit cycle keeps its pace: from the fourth swing of a count on, a swing no larger than the
# one two before it (the last of the same direction) comes within OSC_REGULAR of its
# half-period (a relay-like cycle rises and falls at different paces, 0.12 and 0.36 s on seed
# 7's #6, so the swing just before is no measure). A loop's transient after a kick dies away
# and is not paced so: its recovery swings, then a depth step's jump out of a calm spell (on
# population seed 15's #195, commissioned and in band, half-periods of 0.34 s, then 0.23 and
# 1.15 s: an overshoot that died into the noise, counted as the fourth and alarmed;
# bench_drift seed 16's #0 with a slower servo and no model adopted, 1.24 s, then 1.31 and
# 0.47 s: the next depth step's fall). A swing larger than the one two before is a cycle
# growing, whatever its pace (an entry's cycle on seed 23's #32: 0.09 s, then 0.32 and 0.42 s,
# swings of 81 N, then 953 and 1,315 N). Within 2 the cycles of the generated population's
# seeds 15, 7 and 23 (166 oscillating runs) all keep their pace; within 1.7 two of them lose
# it (a cycle growing on a step's settling mean). A swing that held a spell out of the cut or
# on the gate's own level (_reopen) took the gate's time, not the loop's, and no pace is asked
# of it: a cycle through the air-cut and entry feeds on bench_loop_watch seed 202's #52 took
# 0.68 s for a swing that held the entry feed against 0.24 s for the last of its direction,
# and was alarmed 2.2 s after its onset (0.6 s now).
# A swing out of a calm spell is the program's, a depth step's jump, not the loop's: one that
# took longer than OSC_HALF_MAX_S from the turn before, or whose error stalled in the cut (got
# on by less than the hysteresis, before it last did) for more than OSC_CALM of its
# half-period. A cycle's error gets on all the way to its extreme (from 0.5 to 0.75, the
# oscillating runs of seeds 15, 7, 23, 31 and 43 are alarmed as before, and the false alarms
# below are gone; counting the time from the last gain to the turn's finding as a stall too
# took an entry's jump back into the cut for a calm spell). Commissioned on population seed
# 15's #167 (no model adopted after a dead-time drift), an entry's two swings, then 1.3 s of
# calm after the second and a depth step's rise of 303 N: counted as the third, its return as
# the fourth, alarmed in band, and the reaction left the run at 82.93 N. Such a swing counts
# for nothing on its own but starts a count as a kick's rise: on seed 23's #22 a cycle set off
# by a step after 4.2 s of calm was alarmed 2.7 s after its onset while the rise was left out
# (its return 0.71 of it, the next swing 0.57 of the return). Its half-period is untimed: the
# cycle's mean takes the return's for it.
OSC_REGULAR, OSC_CALM = 2.5, 0.5
# A count begun at such a rise is a cycle only where the loop rings on after the step: its
# third swing at least ONSET_RING of the step's return. A stable loop's recovery after a step
# out of a calm spell dies within a swing (population seed 15's #9, servo slower, the model
# adopted: after 3 s at the table's top, a 3.5 mm step's rise of 868 N and return of 840 N,
# then an overshoot of 50 N, 0.06 of the return, and its fall of 83 N as the settling mean
# went down under it: counted as the fourth, alarmed at 6.65 s, 10.42 N steady with the
# reaction against 1.75 N without). The cycle seed 23's #22 set off had its third swing 0.57
# of the return; a linear loop's transient, 0.15 (above).
# After any kick the third swing is KICK_RING of the return at least: a stable loop's small
# overshoot after a step is no ring (population seed 15's #130, commissioned, in band, 1.8 N
# steady: a 3.5 mm step's rise of 929 N a quarter second after a noise turn, no calm spell,
# its return of 908 N, then 57 N, 0.06 of it, and a fourth of 79 N as the settling mean went
# under it: alarmed at 7.72 s), while a cycle a step set off grew from 0.15 of the return
# (seed 23's #47: 117 N after 793 N). Held to ONSET_RING there instead (stop 33), three deep
# jobs whose cycles ring at under 0.3 of the return were alarmed 0.2-0.4 s late.
# ONSET_RING at 0.15 (stop 39) alarmed a x3.5 step's cycle on an 87 ms loop in time
# (bench_loop_watch seed 6's #16: a relay-like cycle of 290 N after a return of 1,290 N, 0.23 of
# it; at 0.3 the count starts afresh at the cycle's first swing, alarmed 2.38 s after the
# step), but also a commissioned loop in band (population seed 15's #7, the predictive law on a
# 92 ms loop: a step's rise of 578 N out of a calm spell, its return of 628 N, a ring of 188 N,
# 0.299 of it, and 136 N, 0.72 of that: alarmed, 16.6 N steady against 1.95 N). Rings of 0.23
# and 0.3 do not tell a cycle from a loop that settles no better than that: kept at 0.3.
ONSET_RING, KICK_RING = 0.3, 0.1
# A slow cycle is alarmed a swing early: where the last three swings counted took
# OSC_SLOW_HALF_S or more each on the mean, kept a cycle's pace (their half-periods within
# OSC_REGULAR of each other) and did not die away (each at least OSC_DECAY of the one before:
# after a kick the third at least OSC_DECAY of the return, not KICK_RING), the third raises the
# alarm. A cycle's fourth swing comes about 4.4 half-periods after its first swing began (four
# swings, and a turn found once the error is back a third of the swing: 0.39 of a half-period on
# a sine), and the first swing begins at the onset or after it: over 2 s from a half-period of
# 0.45 s, and the onset is as a rule a depth step or an entry before the count's first swing. A
# stable loop's transient does not keep three swings within OSC_DECAY of each other: that is a
# damping ratio under 0.11, a loop as good as cycling. Not where a swing of the count held a
# spell with the loop open for another reason than the gate's air-cut and entry feeds
# (CS_O_SPELLED: the dial, a hold, a stand-down for threading; the shop-floor program's swings
# there are its own); a spell out of the cut counts, its time taken out of the swing's
# half-period (CS_O_SPELL_S: the gate's time, not the loop's). A cycle whose troughs carry the
# force out of the cut spends 0.4-0.5 s of each fall there: bench_loop_watch seed 71's #18 (122
# ms, an underdamped servo) read half-periods of 0.58, 1.02 and 0.37 s with its spell, no pace,
# and was alarmed on its fourth swing 2.34 s after the onset; with the spell's time taken out,
# within 2 s of it. Before the program's exits restarted the count (EXIT_FEED_SHARE) a cut's
# exit, the air and the next entry chained into a count as swings (test_loop_watch's interrupted
# job, no cycle, was alarmed so at its first entry), and any spell kept the early alarm off.
# Measured with the spells out of the cut counted (bench_loop_watch, 60 machines a seed): seeds
# 3-202 below, 644 alarmed in time and 640 calmed as before; 11-59, 645 and 638 (644 and 638);
# 71, 73, 79, 83, 89, 97, 101, 103, 107, 109, 113 and 127 (675 oscillating runs), 657 and 650
# (655 and 649); no alarm in band, none more on runs not oscillating. Nor where the swings keep
# no pace (a commissioned loop in band, bench_drift seed 16's #2 with its dead-time drift
# adopted, was alarmed on a settling swing of 81 N over 1.95 s followed by a depth step's rise
# and return of 238 and 231 N in 0.25 and 0.43 s, and left at 33 N). The cycle's half-period the
# reaction takes is its last two swings' mean (one of each direction: a relay-like cycle rises
# and falls at different paces, and three swings weigh one of them twice). Measured
# (bench_loop_watch, 60 machines): on seeds 3, 5, 6, 7, 8, 9, 15, 23, 31, 43, 61 and 202 (657
# oscillating runs), 641 alarmed within 2 s of the onset and 640 calmed before, 644 and 640 now.
# Swept with ONSET_RING at 0.15 (above: one more in time) and before the spell and pace
# conditions (at 0.35 with them, the same figures), OSC_SLOW_HALF_S 0.3, 0.35, 0.4 and 0.45 gave
# 647 and 636, 645 and 640, 643 and 641, 643 and 641 (the reaction from a cycle measured for
# less calms fewer of the slowest long jobs; at 0.3 with the three swings' mean half-period, 647
# and 633). On seeds not used to choose it (11, 13, 17, 19, 21, 27, 33, 37, 41, 47, 53, 59: 659
# oscillating runs) 643 and 637 before, 644 and 638 now; no alarm in band, nor any more on runs
# not oscillating. Which marginal runs the reaction calms changes with the alarm's time (on the
# 24 seeds, 9 calmed that were not and 8 not that were: long jobs on the slowest loops, at 27-55
# N).
OSC_SLOW_HALF_S = 0.35
# A spell out of the cut is the program's or the loop's. Where the tool leaves the work while
# the axis still feeds (a groove, a cross hole, the part's end), the force's fall to the air
# and its rise at the next entry are the program's swings: the count starts afresh, and the
# fall counts as a kick's rise out of a calm spell (:func:`_left_cut`; the entry's overshoot
# goes on the count only at ONSET_RING of the entry's rise). Where a cycle's trough carries
# the force out of the cut, the loop has stopped the axis: the force is K d f^g, the depth
# unchanged. The test is the axis feed the DAQ measured in the block the tool left in,
# against the level the loop applied over the LEVEL_MEAN_S before (both as shares of the
# 100 % feed): at EXIT_FEED_SHARE of it or more, the program's exit. Measured at the exits of
# eight cycles whose troughs leave the cut (bench_loop_watch: seeds 71's #18, 73's #25, 107's
# #40, 7's #6 and #33, 3's #44, 202's #52, 11's #14): 0.00-0.06; at a groove's, on five
# commissioned machines of population seed 15 cutting 2 mm between grooves of 0.3-0.5 s of
# air every 1-2.5 s: 0.76-2.0. Counted through the spells, those grooves' exits and entries
# made a cycle of the program's: of the first 23 machines of seed 15, commissioned, 22, 15
# and 11 were alarmed with a groove every 1, 1.5 and 2.5 s; 15, 4 and 2 then. The 1 s grooves
# left alarmed were gaps too short for the gate to see the tool leave (the force never under
# exit_force_n in 0.3 s behind a tau_c of 0.15 s): the loop raised the override in the gap,
# and the entry overshot by up to 460 N (now held: FALL_RATE_PER_S). Restarted at the exit
# instead, with the entry's rise the first swing (from wherever the force was as the tool
# came back), the ring after a 3 mm entry on a noisy drive made four swings of 57-106 N
# (bench_loop_watch seed 79's #51, in band, alarmed at 8.86 s). bench_loop_watch on its 36
# seeds: the same runs alarmed in time and calmed, one run fewer alarmed that does not
# oscillate (seed 202's #41, an interrupted job). Where no feed is measured (NaN) the count
# goes on through the spell, as it did; under the alarm too (the reaction's own count,
# :func:`_recycle`).
EXIT_FEED_SHARE, LEVEL_MEAN_S = 0.3, 1.0
# The hold through the tool's exit where the gate has not seen it yet (:func:`_fall`). The
# gate sees the tool leave once the force is under exit_force_n; behind a slow process lag
# the force takes tau_c ln(F / exit_force_n) to get there (0.35 s from 500 N at tau_c 0.15 s),
# and a groove or an interruption shorter than that is never seen: the loop raised the feed
# through the fall and met the work again wound up. On the first 30 machines of population
# seed 15, commissioned, cutting 2 mm with a gap of air every second (bench_grooves.py),
# entries more than 100 N over the reference with gaps of 0.1, 0.2, 0.3 and 0.5 s: 29, 30, 23
# and 4 of 30 (up to 898 N), and 21, 19, 13 and 0 alarmed as cycles; with the hold 1, 2, 1
# and 0 (132 N at most), none alarmed. The force's fall tells the tool's exit from a smaller
# depth by where it heads, F + tau_c dF/dt with the model's process lag (C_TAU_C): under
# FALL_HEADING_SHARE of the reference, the force falling faster than FALL_RATE_PER_S of it a
# second (the estimate's rate in a steady cut: 1.7 at most on those machines), with the axis
# still feeding at FALL_FEED_SHARE of its mean over FALL_FEED_MEAN_S or more and at
# EXIT_FEED_SHARE of the loop's level (a limit cycle's force falls after its feed). Until
# that has held FALL_SURE_S, the request does not rise; then the level held is the axis
# feed's mean while the force was within FALL_NEAR_SHARE of the reference and calm
# (FALL_CALM_RATE_PER_S, over FALL_BASE_MEAN_S; the level sent then was a law's transient:
# once 150 % at the entry feed's end), or the gate's entry feed where the force has not been
# there since the tool entered, shaped by the error feedback like the reaction's level, and
# never above the level sent. The hold ends once the force is back at the reference, or
# heads for FALL_STAYS_SHARE of it or more and does not rise fast for FALL_CALM_S (the tool
# back in, or a smaller depth: with a model's tau_c 2.5 times the machine's the fall of a
# 3 -> 1 mm step reads as an exit for its first periods), or after FALL_HOLD_MAX_S. For the
# detector the hold is a spell of the loop open, as the gate's air (:func:`_left_cut`). Not
# under the oscillation reaction, which sets the feed itself (held, the detune reaction
# entered the next cut from the level held, under the gate's air feed, and crept to the
# reference: seed 15's #119, SMC on the true model, 4.96 -> 10.52 N steady).
# bench_loop_watch's 36 seeds (uncommissioned: tau_c 0.05 s in the model, 0.02-0.2 s in the
# machines): no alarm in band; the runs alarmed within 2 s and calmed under the reaction the
# same but two: seed 109's #35 (tau_c 0.021 s, alarmed 10 s late before, not at all now: with
# the model's tau_c 2.4 times its own, depth decreases read as exits and restart the count)
# and seed 79's #36 (alarmed at the same 1.23 s, no longer oscillating by the issue's
# criterion once its exits are held).
FALL_RATE_PER_S, FALL_HEADING_SHARE, FALL_FEED_SHARE, FALL_FEED_MEAN_S = 2.5, 0.1, 0.8, 0.1
FALL_NEAR_SHARE, FALL_BASE_MEAN_S, FALL_STAYS_SHARE = 0.1, 0.3, 0.2
FALL_CALM_RATE_PER_S, FALL_CALM_S, FALL_HOLD_MAX_S = 1.0, 0.05, 1.0
FALL_SURE_S = 0.02
FALL_NONE, FALL_PENDING, FALL_HELD = 0, 1, 2
# Under the reaction the detector asks whether the reaction's own loop cycles: a swing counts
# only REACTION_HALF_RATIO times the alarmed cycle's half-period at most (a PI law that
# cycles does so where the process's phase is between -90 and -180 degrees: above w_u / 4 on
# the population's loops, dead time and lags), and no kick counts: a depth step's slow return
# under the reaction (half-periods of 1.8 s against the cycle's 0.19 s) and its small
# overshoot after a x3 step were read as the reaction cycling, and halved the crossover of 4
# of the 9 runs the reaction left over the ripple bound on seeds 7 and 23.
# A slower cycle of the reaction's own counts too where its swings keep their pace (each
# half-period within REACTION_REGULAR of the mean of those counted before it: a depth step's
# slow return is one long swing between short ones; the log law's cycle rises faster than it
# falls, half-periods of 0.64 and 1.04 s in turn). Such a cycle said that the alarmed one was
# not the loop's own: on bench_drift's seed 37 #4 (PMC dead time 145 -> 218 ms, commissioned)
# the SMC's fast ring (half-periods of 0.09 s) set the crossover at 6.8 rad/s, above the
# loop's w_u (about 7.3: 218 ms, a 0.28 s servo, tau_c 0.066 s), and the reaction cycled at
# half-periods of 0.6-1.0 s with 300-1,400 N swings for the rest of the job, unseen. Its
# crossover is then at most the reaction's cycle's frequency over RECYCLE_RATIO (a PI law
# cycles where the process's phase is -90 to -180 degrees; half that frequency leaves it
# about 60 degrees of margin), the cycle's half-period over RECYCLE_RATIO stands for the
# alarmed one from then on (the crossover's ceiling and the step answer's lags), and the level
# restarts from the reaction's cycle's mean. Swings in the first SETTLE_HALVES of the alarmed
# half-periods after the alarm are not counted: the alarmed cycle dies away under the reaction
# there (swings of 0.82, 0.67 and 1.12 of the one before on seed 23's #44, counted as the
# reaction cycling, halved its crossover and left it 83 N over the ripple bound, 44 N without;
# calmed on the held-out seeds 31 and 61: 52 and 49, from 51 and 48; seeds 15, 7, 23, 43 as
# before).
REACTION_HALF_RATIO = 4.0
REACTION_REGULAR, RECYCLE_RATIO, SETTLE_HALVES = 2.0, 2.0, 4.0
# The detune reaction: the limit cycle's frequency w_u = 2 pi / T_u bounds the loop's. The
# force being about proportional to the feed (F = K u, K set by the depth), the law works on
# logarithms, where the process is a gain of 1 whatever K: a PI law on the relative feed,
#   d ln u / dt = -w_c ln(F / F_ref) - DETUNE_P d ln(F / F_ref) / dt,
# whose integral part alone would bring ln F to ln F_ref as a first-order lag of rate w_c from
# any depth step, up or down, and whose proportional part answers a depth step's jump of ln F
# at once with DETUNE_P of it (a feed-forward of the depth change through the force/override
# ratio). w_c = w_u / DETUNE_RATIO keeps a phase margin of about 40 degrees on a loop of dead
# time, servo and tau_c whose phase at w_u was -180 (Astrom & Hagglund, PID Controllers, 1995,
# Sec. 2.9 and 4.3); the proportional gain, below 1 / 1.75 (the resonance of a servo damped at
# 0.3, the population's least), cannot close a cycle on its own (small gain). The force is
# taken at least LOG_FLOOR of the reference (the gate's exit threshold is a tenth of it). Where
# the detector still finds a cycle under the reaction, w_c is halved, as often as it does.
# Measured on the generated population (seeds 15, 7, 5, 6, 8, 9: 330 oscillating runs): 258
# calmed by the integral law on the linear error at w_u / 6, the log law without the
# proportional part 187 of the 223 of seeds 15, 7, 5, 6 (169 before) at w_u / 4, and 312 of
# 330 with it and DETUNE_P 0.4 at what was meant as w_u / 3 but ran at w_u / 6 (the alarm's own
# count halved the crossover the period after it was raised). At w_u / 3 the reaction cycles
# on its own on loops with g near 1 (44 and 50 of the 54 and 59 oscillating runs of seeds 15
# and 7 calmed, against 49 and 53 at w_u / 6); the ones left at w_u / 6 are long jobs on slow
# loops and light cutting exponents (g about 0.6 halves the loop's gain, d ln F = g d ln u),
# still 20-60 N off the reference 2 s after a depth step of x0.4 or x3. A larger proportional
# part takes more of each step at once: with DETUNE_P 0.55 (under the small-gain bound) and
# w_u / 5, 53 and 56 of them (w_u / 4.5, 6, 7 and DETUNE_P 0.5, 0.7 gave 48-54 and 55-57), and
# seeds 5 and 6 unchanged (50 of 53, 53 of 57).
# (Relay auto-tuning's PI, Tyreus-Luyben's K_u / 3.2 and 2.2 T_u from the cycle read as a relay
# experiment, was tried in its place: on the generated population it left the loops slower
# after each depth step and fewer of them under the ripple bound: its integral time, 2.2 T_u,
# is too long for a depth step every 3 s.)
# The law is stepped as it is written, on the logarithm: u times exp(-step) (1 - step, its
# first order, took too much off after a rise and too little after a fall).
DETUNE_RATIO, DETUNE_P, LOG_FLOOR = 5.0, 0.55, 0.1
# Calm but not sluggish: w_u / DETUNE_RATIO is safe on every loop, slow on the slowest (a
# depth step's error still 25-40 N off 2 s after it). The reaction times its own returns:
# where an excursion of ln(F / F_ref) beyond TAIL_HIGH comes back to TAIL_LOW without
# overshoot at less than TAIL_RATE_PER_S, the crossover is raised by the ratio (a pattern-
# recognising retune, as Foxboro's EXACT: Kraus & Myron, Control Engineering, 1984),
# at most to w_u / FASTEST_RATIO. The ripple bound asks the 1 s from 2 s after a step to stay
# within 25 N (0.05 of the reference): a residue of 0.6 (a x3 step after the proportional
# part) decays under that at about 2 per second. At w_u / 3 the reaction cycled on its own on
# loops with g near 1 (above); w_u / 3.5 is the most it is given. Tried and left: the cycle's
# amplitude ratio as the loop's gain margin (a describing function: the relative swing of the
# force over that of the feed; the uncommissioned SMC's cycle is a relay's, 0-150 %) to speed
# the reaction up to a gain margin of 3 or 5: it did not tell the loops that settle faster
# from those that overshoot (ratios 0.15-0.35 on both), 44-52 of the 54 of seed 23 calmed.
TAIL_HIGH, TAIL_LOW, TAIL_RATE_PER_S, FASTEST_RATIO = 0.15, 0.05, 2.0, 3.5
# The law starts from the level the force implies, the force being about proportional
# to the feed: the level held scaled by ENTRY_SHARE F_ref / F, so that the force approaches from
# below, after the gate has set the feed (the air, an entry, the dial), once the force has
# settled there: at least ENTRY_FORCE_SHARE of the reference, changing by less than
# ENTRY_RATE_PER_S of itself per second, and at most ENTRY_RAISE times the gate's level (a
# force read at a turning point, not settled, must not send the feed far). The law waits on the
# gate's level until then. Tried and left: starting so at the alarm itself (the cycle's mean
# force, taken over an entry's transient, sent it further off than its mean level), and
# jumping so mid-cut where the force had settled far from the reference after a depth step
# (the force's rate is as small at a cycle's turning points as where it has settled: a jump
# taken at a trough sent one machine's force to 2,100 N).
ENTRY_SHARE, ENTRY_FORCE_SHARE, ENTRY_RATE_PER_S, ENTRY_RAISE = 0.9, 0.1, 0.5, 2.0
# The detune reaction's answer to a depth step down. On the slowest loops (dead time 90-147
# ms, servo 0.25-0.33 s) the crossover's ceiling, w_u / FASTEST_RATIO, still left a x0.4 depth
# step 25-35 N off 2 s after it: with about 0.6 s of loop lag no PI law gets there (issue
# 16's note). A depth step is no cycle: the force jumps by the depth's ratio while the feed has
# not moved (F = K a f^g), and the feed that brings it back is known at once, f exp(-d / g), d
# the jump of ln F. Once the force has been calm (ln(F / F_ref) within STEP_CALM) for
# STEP_CALM_HALVES of the alarmed cycle's half-periods, a fall below the calm band at a rate
# -d ln F / dt above STEP_RATE_PER_S (the calm periods' noise on seed 15's machines: p99 of
# |d ln F / dt| 1-3 /s, beyond the band only with a step) is a step. Until the force is back
# within TAIL_LOW, and for STEP_WINDOW_HALVES half-periods at least, the level is then set by
# internal model control (Morari & Zafiriou, Robust Process Control, 1989, Ch. 3): d = ln F -
# ln F0 - g (the level's moves since the step, through the model), the level f0 exp(-d / g),
# g the feed exponent the laws assume (model_cutting_exponent). The model of the level's way
# to the force is two lags of STEP_LAG_HALVES / 2 half-periods each: the cycle's half-period
# is about the loop's dead time and lags together (its phase -180 degrees at w_u). The
# model's error, the feed's true exponent (0.6-1 on the population against the default 1)
# included, stays in d and is taken out as an integral would. An overshoot beyond STEP_CALM
# ends it too; the PI law takes over from the level reached, so that it does not see the
# feed's arrival as a step (it would take back its proportional share, DETUNE_P, of it). The
# swings of the step's answer are not the reaction cycling: the detector's count is kept at
# 0 meanwhile. Measured on seeds 15, 7 and 23 (166 oscillating runs): 164 calmed against
# 159 by the PI law alone, the slowest long jobs 7-19 N after x0.4 steps (27-43 N); on seeds
# not used to tune it, 31, 43 and 61: 51, 58 and 48 of 54, 58 and 53 (50, 56, 48). Steps up
# are the PI law's: answered so too, the model's lag (a half-period) is far quicker than a
# loop whose lag is mostly a slow servo's (the lag 3.3 half-periods on seed 23's #42), the
# level fell to 0-10 % for a step to 27 %, and at such levels the table's 10 % steps are half
# the level: three runs the PI law had calmed were left 26-37 N over (161 calmed); with the
# level's move held within the force's jump over an exponent of 0.6, two of them still were,
# and another stood 100 N over. The model's lag at 1.5 half-periods instead left the slow
# loops 28-55 N off.
STEP_CALM, STEP_CALM_HALVES, STEP_RATE_PER_S = 0.1, 2.0, 1.5
STEP_WINDOW_HALVES, STEP_LAG_HALVES, STEP_CALM_MEAN_S = 3.0, 1.0, 0.1
# What was left after a step up: on the slowest long jobs (half-periods of 0.26-0.5 s, the
# crossover at 1.3-2.4 rad/s) the force still came back from a x3 depth step up as a slow
# first-order tail, 26-44 N of ripple 2-3 s after it (seed 23's #1 and #44, 31's #23 and #56,
# 61's #1, #5, #28 and #47). The PI law's proportional part answers the rise, then gives it
# all back as the force returns (its net is DETUNE_P times the share's change, 0 once back),
# so the whole move of the level, ln 3 / g, is the integral's at w_c. A step up (the force
# calm for STEP_CALM_HALVES half-periods, then rising at STEP_RATE_PER_S or faster) keeps
# RISE_KEEP of its rise (ln F's, from the calm mean to the peak) as a move of the level, once,
# at the peak, where the rise took RISE_HALVES of the alarmed half-period at least from its
# finding to its peak. The kept move is well under what the step asks (ln 3 / g, g 0.6-1),
# but the integral runs on the rise too until the feed's move arrives: where the force rose
# faster than that (tau_c 0.02-0.05 s, peaks 0.12-0.18 s after the step, 0.46-0.51 of the
# half-period, against 0.27-0.36 s and 0.55-0.91 where the tail was slow), the kept move on
# top overshot (seed 23's #32 and 43's #45, calmed without it, were left 25-27 N over). Tried
# and left: the rise kept all along it (at 0.45, 1 / g - DETUNE_P: 51 and 52 of seeds 23 and
# 15 calmed), nothing of the return given back (the integral overshot), the integral paused
# while the force falls fast. Measured (bench_loop_watch, 60 machines): seeds 15, 7, 23 calmed
# 53, 59, 53 (53, 59, 52 before), held-out 31, 43, 61 53, 58, 50 (52, 58, 49); RISE_KEEP 0.2:
# 53, 59, 53 and 52, 58, 50; 0.45: 52, 59, 52 and 53, 58, 51; RISE_HALVES 0.6: 31 and 61 as
# before. (The gate's half-period ratio was read off the held-out seeds' runs too.)
FF_WATCH, FF_STEP, FF_RISE = 0, 1, 2
RISE_KEEP, RISE_HALVES = 0.3, 0.5
# The detune reaction where the DAQ measures the axis feed (CS_O_FEED): the level from the
# cut's own force per feed, read off the feed the axis made. F = K d f^g behind the cut's lag:
# ln(F / F_ref) less g times the log of the measured feed's share (lagged as the force lags
# the feed) is ln(K d / F_ref), the cut's alone, whatever the feed does; the level that
# brings the force to the reference is its exp(-1 / g) (internal model control, Morari &
# Zafiriou, Robust Process Control, 1989, Ch. 3, with the measured feed as the model's input:
# a disturbance observer). The PMC's dead time and the servo are then outside the loop: a
# force that follows the feed's own ring is explained by the feed and not answered. The PI
# law answers it: on a lightly damped servo (6-20 rad/s, damping 0.4-0.5) a x3 depth step's
# override move of 140 -> 40 % rang the feed from 0.28 down to 0.03 mm/rev and up to 0.14,
# and the law chased the ring: bench_loop_watch seed 107's #40 still swung 300-850 N 1-3 s
# after the step (196 N of ripple after the reaction; 11 N so). The depth's moves are the
# model's disturbance, answered at once, up or down. What stays in the loop is the model's
# error. (a) The exponent: a level that moves ln u makes the model read (g / g_m - 1) ln u of
# it as the cut's, so the next level moves by 1 - g / g_m of the last: a contraction
# wherever g < 2 g_m, which reaches the level the cut needs from the first move's side (short
# of it where the cut's exponent is lighter than the model's, beyond it where heavier). The
# population's (and Kienzle's, for steels) g lies at 0.6-1 while the default model says
# Park's 1 (g 0.62 left a x3 step's force a slow tail, 0.38 of each move left over: seed 8's
# #34, 31 N 2 s after the step): taken at REACTION_EXPONENT_SHARE of the model's, 0.8, the
# middle of that range, the contraction is 0.25 at most either way, and 0.25 on an identified
# exponent. (b) The lag: a model lag shorter than the cut's reads the force's late answer to
# a feed move as the cut's and over-answers (an overshoot of its own), a longer one answers
# less: REACTION_LAG_S, the middle of the population's tau_c (0.02-0.2 s), not the default
# model's 0.05 s. Measured (bench_loop_watch, 60 machines, seeds 3-202: 657 oscillating runs,
# 640 calmed by the PI law): the model's lag and exponent, 645; the exponent at 0.8 of it,
# 647; with the lag at 0.1 s, 652 (0.15 s: 647, a fast cut's servo ring answered late, seed
# 3's #21 at 395 N; a first-order lag on the level of 0.03 or 0.05 s: 652, 651). An integral
# on the force's error beside it (at the PI law's crossover, or 0.3 of it) was tried and
# left: it winds up while the servo brings the feed, an error the model already holds, and
# the loops cycled (none of 13 calmed that the observer alone mostly did). The measured feed
# is floored at REACTION_FEED_FLOOR of the 100 % feed (a stopped axis has no log). Where no
# feed is measured (NaN), or once it is lost, the PI law below takes over from the level held.
# With FEED_CYCLE_RATIO and FEED_RISE_HALVES below, seeds 3-202: 652 of the 657 calmed (640
# by the PI law); on seeds not used to choose them, 11-59: 655 of 659 (638), 71-127: 668 of
# 674 (648); no run alarmed in band, none held on overload after its alarm, and the alarms as
# before (the reaction starts after them). Of the 15 left, 5 are never alarmed (a depth
# step's settling meets the criterion), 9 are long jobs on the slowest loops (dead
# time 102-144 ms: 25-59 N in the second before the next step, 2-3 s after a x3 step; on a
# servo damped at 0.4 the level holds from the step on and what is left is the servo's own
# ring after the move, 80 -> 20 %: seed 33's #56), and one an interrupted cut after a servo
# drift (seed 59's #2, 31 N).
REACTION_EXPONENT_SHARE, REACTION_LAG_S, REACTION_FEED_FLOOR = 0.8, 0.1, 0.02
# The law on the feed can cycle on its own: where the cut is much faster than REACTION_LAG_S
# and the servo lightly damped, the force's answer to the feed's ring runs ahead of the
# model's and the level answers it as a proportional law would, through the servo's
# resonance (seed 21's #45: tau_c 0.027 s, a servo of 18.5 rad/s damped at 0.33: a 0.3 s
# cycle of 50-150 %). Where the detector counts a cycle under it (:func:`_recycle`) no slower
# than FEED_CYCLE_RATIO times the alarmed half-period, the law reads the cut through a lag of
# the cycle's half-period (doubled at each cycle after), which takes the loop's gain at the
# cycle down. Slower ones are a long job's depth steps settling, no cycle of the law's: on
# seeds 5's #7, 61's #28 and 33's #8 the detector counted half-periods of 1.28-1.51 s, 13-15
# s after the alarm, against cycles of 0.31-0.42 s; answered, they left the next steps 74-103
# N off (calmed without). The cycles of the law's own on seeds 21's #45, 13's #0 and 97's #5:
# 0.16-0.51 s against 0.26-0.31 s. Handing the loop to the PI law at such a cycle instead
# calmed 652 runs of seeds 3-202, the lag 653 (and 13's #0, 97's #5 and 113's #36 at 26-80 N
# under the PI law, 7 N with the lag; 21's #45 at 71 N, where the lag came too late). A lag
# of a third of the alarmed half-period from the alarm on, before any cycle: 641.
FEED_CYCLE_RATIO = 2.0
# The law on the feed lowers the level at once and raises it through a lag of
# FEED_RISE_HALVES of the alarmed half-period. A rise answers a force under the reference (an
# entry after the gate's entry feed, a depth step down), where a feed that comes a little late
# costs no tool; taken at once, the jump into a lightly damped servo overshot: on
# bench_entries seed 42 the uncommissioned defaults (alarmed, their reaction running) entered
# at 81, 26, 142, 73, 28, 269 and 140 N over the reference on #2, #4, #8, #16, #19, #32 and
# #36 (65, 15, 118, 49, 15, 224 and 134 N under the PI law), 66, 17, 119, 56, 18, 224 and 113 N
# with the lag. On bench_loop_watch it calmed 652, 655 and 668 on seeds 3-202, 11-59 and
# 71-127 (653, 655 and 668 without; half a half-period, 650 on 3-202: a x0.4 step's recovery
# slower), and seed 21's #45 was no longer held on overload (its level rose slower into the
# x3.5 step).
FEED_RISE_HALVES = 0.25
# Where the law adopts the model of a lag drift the monitor named (drift_adopt_model), the loop
# answers the switch as it would a kick: the old model's ring dies away over about the
# monitor's window (drift_memory_s), which is how long the drift took to be named. Its swings
# are the old loop's, not the new one's: the detector starts afresh and counts none for
# ADOPT_SETTLE windows. Chained with a depth step's rise and return they made four (bench_drift
# seed 29 #5, servo x1.8: a dying ring of 133 and 165 N 0.3 and 1.3 s after the switch, then a
# 1 -> 2 mm step, alarmed at 5.04 s; the same loop on the drifted model from the start, no
# alarm).
# Where the oscillation alarm already holds when the model is taken (the drifted loop rang
# before the monitor named the drift), the reaction lets go: the ring was the drifted loop's,
# the model taken is its cure (a loop on the model it runs on, as commissioned), and the
# detuned reaction would hold the loop slow to the end of the run. The detector starts afresh
# as above; a loop that rings on the adopted model too is alarmed again, and the reaction then
# holds (it lets go once per tool: only at the first model taken). bench_drift seed 16 #2
# (smc, dead time 102 -> 153 ms) with a 2 s window: alarmed at 4.38 s, named at 4.43 s, 24.7 N
# steady with the reaction held, 3.1 N let go (ripple 100 -> 7 N); seed 29 #5 (mpc, servo
# x1.8): alarmed at 3.32 s, named at 4.22 s, 82.8 -> 30.8 N (in band from 6.5 s on: what is
# left is the ring before the drift was named).
ADOPT_SETTLE = 1.0
# oscillation_reaction's index in law.OSCILLATION_REACTIONS
DETUNE, HOLD_MEAN, PROGRAMMED_FEED, NO_REACTION = 0, 1, 2, 3
# The reaction's request goes to the PMC through the error-feedback quantiser whatever the
# ``quantiser`` setting (the law's own requests keep it): the detune reaction is a continuous
# law on the feed, and the mean it holds (hold_mean) is a level between two of the table's as a
# rule; rounded to the nearest level, a request between two levels whose force lies on either
# side of the reference cycles between them at the pace of the reaction's own integral, a
# limit cycle of the reaction's making. bench_drift.py seed 53 #0 (mpc commissioned, Park's
# file's nearest quantiser, a 'deep' job, process gain +40 %): after the x3.5 step, 10 % gave
# 761 N and 0 % none; the loop cycled, was alarmed, and the reaction asked for 4.4-7.7 %, sent
# as 0 % or 10 % for 0.15-0.35 s at a time: 71.06 N steady, 443 N of ripple. Noise-shaped, the
# levels alternate every period, the servo and tau_c average them: 2.65 N, 4.9 N.

_laws = dispatch.load()
law_step, law_reset, law_finite, law_sent = _laws.step, _laws.reset, _laws.finite, _laws.sent
law_adopt = _laws.adopt


@compiled
def _mean(mean: float, value: float, cp: np.ndarray, time_s: float) -> float:
    """``mean`` one control period further toward ``value``: a first-order mean over
    ``time_s``."""
    return mean + (value - mean) * pymin(cp[C_PERIOD] / time_s, 1.0)


@compiled
def _track_reach(cp: np.ndarray, cs: np.ndarray, request: float, error: float) -> float:
    """1.0 while the reference can be reached, else 0.0 (:class:`..control.Controller`). The
    force reaches the reference when the error's mean over :data:`REACH_MEAN_S` does, not a
    sample of it: a cut's own fluctuation (a few % of the force) crosses a reference a few
    newtons out of reach many times a second, and each crossing restarted the clock."""
    tolerance = pymin(cp[C_GAP] / 2.0, 5.0)
    side = 0
    if request >= cp[C_MAX] - tolerance and error < 0.0:
        side = 1
    elif request <= cp[C_MIN] + tolerance and error > 0.0:
        side = -1
    pinned_side = int(cs[CS_SIDE])
    if pinned_side != 0:
        cs[CS_PIN_ERROR] = _mean(cs[CS_PIN_ERROR], error, cp, REACH_MEAN_S)
    if side != 0 and side == pinned_side:
        cs[CS_PINNED] += cp[C_PERIOD]
    elif side != 0:
        cs[CS_SIDE], cs[CS_PINNED], cs[CS_PIN_ERROR] = side, cp[C_PERIOD], error
    else:
        mean = cs[CS_PIN_ERROR]
        reached = (pinned_side == 1 and (mean >= 0.0 or request
                                         < cp[C_MAX] - 2.0 * tolerance)) or (
            pinned_side == -1 and (mean <= 0.0 or request > cp[C_MIN] + 2.0 * tolerance))
        if reached:
            cs[CS_SIDE], cs[CS_PINNED] = 0.0, 0.0
    return 1.0 if cs[CS_PINNED] < cp[C_UNREACH] else 0.0


@compiled
def _recover(cp: np.ndarray, cs: np.ndarray, error: float, out: np.ndarray) -> None:
    cs[CS_RESETS] += 1.0
    cs[CS_CARRY] = 0.0
    law_reset(int(cp[C_KIND]), cp, cs)
    out[OUT_PCT] = cs[CS_HELD]
    out[OUT_ERR] = error if math.isfinite(error) else 0.0
    out[OUT_S] = 0.0
    out[OUT_REACH] = 1.0


@compiled
def _further(direction: float, a: float, b: float) -> float:
    """Of ``a`` and ``b``, the one further the way the detector watches the error go
    (``direction``: 1 rising, -1 falling; 0, none watched: ``a``)."""
    if direction > 0.0:
        return pymax(a, b)
    return pymin(a, b) if direction < 0.0 else a


@compiled
def _turn(cp: np.ndarray, cs: np.ndarray, extreme: float) -> None:
    """The error turned at ``extreme``: the swing from the turn before counts toward the
    alarm if it is large, took OSC_HALF_MIN_S to OSC_HALF_MAX_S, and the cycle does not die
    away: the last two swings together (a period's peak to peak) at least OSC_DECAY of the two
    before; the third after a kick at least KICK_RING of the kick's return (after a kick's
    rise out of a calm spell ONSET_RING of it), the fourth at least
    OSC_DECAY of the third; from the fourth on, each no larger than the one two before within
    OSC_REGULAR of its half-period. A slow cycle (OSC_SLOW_HALF_S) whose last three swings
    keep their size (each at least OSC_DECAY of the one before) and their pace (their spells
    out of the cut not timed), none of them through a spell with the loop open for another
    reason, raises the alarm a swing early.
    Otherwise the count starts afresh, at the swing itself where
    it counts, or where it is large and came out of a calm spell (OSC_CALM: a kick's rise).
    Under the alarm (the reaction running), no kick, no swing in the first SETTLE_HALVES
    alarmed half-periods, and a swing goes on the count where it and those counted before it
    took REACTION_HALF_RATIO times the alarmed cycle's half-period at most, or where it took
    within REACTION_REGULAR of their mean (a slower cycle of the reaction's own)."""
    swing, half = abs(extreme - cs[CS_O_LAST]), cs[CS_O_SINCE]
    if cs[CS_O_WIGGLE] != 0.0:
        # the turn after the noise's: the swing before the wiggle ends here where further
        cs[CS_O_WIGGLE] = 0.0
        cs[CS_O_LAST] = _further(cs[CS_O_DIR], cs[CS_O_LAST], extreme)
        return
    if swing < cp[C_OSC_SWING] and half < OSC_HALF_MIN_S:
        # a wiggle of the noise at the swing's extreme: the swing and its turn stand
        cs[CS_O_WIGGLE] = 1.0
        return
    last, before = cs[CS_O_SWING], cs[CS_O_SWING_BEFORE]
    watching = cs[CS_O_ALARM] == 0.0
    large = swing >= cp[C_OSC_SWING] and (
        cs[CS_O_AGE] >= 0.0 if watching else cs[CS_O_AGE] >= SETTLE_HALVES * cs[CS_O_HALF])
    calm = half > OSC_HALF_MAX_S or (watching and cs[CS_O_STALL] > OSC_CALM * half)
    counts = large and half >= OSC_HALF_MIN_S and not calm
    onset = large and watching and calm   # a kick's rise, untimed
    chains = True
    spelled = cs[CS_O_REOPEN] == 2.0
    cs[CS_O_REOPEN] = 0.0
    opened, net = cs[CS_O_OPENED] != 0.0, half - cs[CS_O_SPELL_S]
    cs[CS_O_OPENED], cs[CS_O_SPELL_S] = 0.0, 0.0
    if watching and cs[CS_O_COUNT] >= 3.0 and swing < before and not spelled:
        # a cycle's pace: within OSC_REGULAR of the swing of the same direction (a swing
        # that held a spell out of the cut or on the gate's level took the gate's time)
        paced = cs[CS_O_HALF_BEFORE]
        chains = half <= OSC_REGULAR * paced and paced <= OSC_REGULAR * half
    elif cs[CS_O_ALARM] != 0.0 and cs[CS_O_COUNT] > 0.0:
        # under the reaction: a swing within REACTION_HALF_RATIO of the alarmed half-period
        # after others as fast, or one about as long as the swings counted before it (a cycle
        # of the reaction's own, however slow)
        fast = REACTION_HALF_RATIO * cs[CS_O_HALF]
        counted = cs[CS_O_HALVES] / cs[CS_O_COUNT]
        chains = (half <= fast and counted <= fast) or (
            half <= REACTION_REGULAR * counted and counted <= REACTION_REGULAR * half)
    kicked = cs[CS_O_COUNT] == 2.0 and cs[CS_O_ALARM] == 0.0 and (
        cs[CS_O_GREW] != 0.0 or last >= OSC_DECAY * before)
    rings = swing >= (KICK_RING if cs[CS_O_ONSET] == 0.0 else ONSET_RING) * last
    lasting = (kicked and rings) or swing >= OSC_DECAY * last or (
        cs[CS_O_PAIRED] != 0.0 and swing + last >= OSC_DECAY * (last + before))
    cs[CS_O_GREW] = 1.0 if swing >= last else 0.0
    cs[CS_O_PAIRED] = 0.0 if kicked else 1.0
    early = False
    if counts and cs[CS_O_COUNT] > 0.0 and lasting and chains:
        cs[CS_O_COUNT] += 1.0
        # after an untimed first swing (none summed) this one's half-period twice
        cs[CS_O_HALVES] += half * (2.0 if cs[CS_O_HALVES] == 0.0 else 1.0)
        # a slow cycle, its last three swings sustained and paced: alarmed a swing early
        cs[CS_O_SPELLED] = 1.0 if opened else cs[CS_O_SPELLED]
        a, b = cs[CS_O_NET_BEFORE], cs[CS_O_NET_LAST]
        slowest, fastest = pymax(pymax(a, b), net), pymin(pymin(a, b), net)
        early = (watching and cs[CS_O_COUNT] >= 3.0 and cs[CS_O_SPELLED] == 0.0
                 and cs[CS_O_COUNT] == cp[C_OSC_COUNT] - 1.0
                 and swing >= OSC_DECAY * last and last >= OSC_DECAY * before
                 and slowest <= OSC_REGULAR * fastest
                 and a + b + net >= 3.0 * OSC_SLOW_HALF_S)
    else:
        cs[CS_O_COUNT] = 1.0 if counts or onset else 0.0
        cs[CS_O_ONSET] = 1.0 if onset else 0.0
        cs[CS_O_SPELLED] = 1.0 if opened else 0.0
        cs[CS_O_HALVES] = half if counts else 0.0
    # the level sent over the cycle: from the third swing on after a kick (the two before are
    # the step's, not the loop's; where the third raises the alarm, the return's too, or the
    # level would be half a period's), none of a calm spell
    restart = (kicked and not early) or cs[CS_O_COUNT] <= 1.0
    timed = not onset
    cs[CS_O_CSUM] = (cs[CS_O_HSUM] if timed else 0.0) + (0.0 if restart else cs[CS_O_CSUM])
    cs[CS_O_CTIME] = (half if timed else 0.0) + (0.0 if restart else cs[CS_O_CTIME])
    cs[CS_O_HSUM] = 0.0
    cs[CS_O_LAST], cs[CS_O_SWING_BEFORE], cs[CS_O_SWING] = extreme, last, swing
    cs[CS_O_HALF_BEFORE], cs[CS_O_HALF_LAST] = cs[CS_O_HALF_LAST], half
    cs[CS_O_NET_BEFORE], cs[CS_O_NET_LAST] = cs[CS_O_NET_LAST], net
    cs[CS_O_SINCE] = 0.0
    if early:   # the alarm (_watch), at the last two swings' half-period (OSC_SLOW_HALF_S)
        cs[CS_O_COUNT] = cp[C_OSC_COUNT]
        cs[CS_O_HALVES] = cp[C_OSC_COUNT] * 0.5 * (cs[CS_O_NET_BEFORE] + net)


@compiled
def _implied(cp: np.ndarray, level: float, force: float) -> float:
    """The level that brings the force ``force`` at ``level`` to ENTRY_SHARE of the reference
    (the force about proportional to the feed), at most ENTRY_RAISE times ``level``."""
    return clip(cp, level * pymin(ENTRY_SHARE * cp[C_REF] / pymax(force, 1e-9), ENTRY_RAISE))


@compiled
def _alarm(cp: np.ndarray, cs: np.ndarray, error: float) -> None:
    """The alarm is raised: the level the reaction starts from (the cycle's mean), and the
    detune reaction's crossover from the limit cycle's period (twice the counted swings' mean
    half-period, at least the identified model's, ``C_MODEL_HALF``: a commissioned law's
    cycle can be its own predictor's, faster than the loop's, a 0.09 s half-period on a loop
    whose model said 0.33 s), and its ceiling."""
    cs[CS_O_ALARM] = 1.0
    cs[CS_O_ALARMS] += 1.0
    reaction = int(cp[C_OSC_REACTION])
    # the counted cycle's mean level (its time is its counted half-periods', never 0): the
    # last second's mean held the level before a depth step that kicked the cycle off (once
    # 35 % against a cycle about 20 %, and a 380 N overshoot)
    mean = cs[CS_O_CSUM] / cs[CS_O_CTIME]
    cs[CS_O_HOLD] = clip(cp, 100.0 if reaction == PROGRAMMED_FEED else mean)
    cs[CS_O_WAIT] = 0.0
    cs[CS_O_HALF] = pymax(cs[CS_O_HALVES] / cs[CS_O_COUNT], cp[C_MODEL_HALF])
    period = 2.0 * cs[CS_O_HALF]
    cs[CS_O_CROSSOVER] = 2.0 * math.pi / (period * DETUNE_RATIO)
    cs[CS_O_TOP] = 2.0 * math.pi / (period * FASTEST_RATIO)
    cs[CS_O_AGE] = 0.0
    cs[CS_O_TAIL] = -1.0
    cs[CS_O_LOG_FORCE] = _log_share(cp, error)
    cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME], cs[CS_O_FF_SHARE] = FF_WATCH, 0.0, 0.0
    # on the feed where measured (_model_feed)
    cs[CS_O_BY_FEED], cs[CS_O_MODEL_FEED], cs[CS_O_CUT], cs[CS_O_CUT_S] = 1.0, math.nan, \
        math.nan, 0.0


@compiled
def _reopen(cs: np.ndarray, error: float, rate: float) -> None:
    """The first period watched after a spell out of the cut or with the loop open (the gate
    held a level of its own: the air-cut feed, the entry feed, the dial; :func:`_out_of_cut`
    followed the swing's extreme meanwhile, turning nothing). Where the force now runs the way
    the swing went (``rate``, the estimate's rate), the gate's level moved it on its own in
    the spell, and the loop's swing ends where the force turns from now on: the extreme of the
    spell is kept (CS_O_FLOOR) and the turn found later measures the swing to the further of
    the two. A limit cycle whose troughs carry the force under the gate's exit threshold
    leaves the cut at each of them; at the next entry the force overshoots on the entry feed
    and falls back as the loop takes over. With the trough in air as the extreme, that fall
    turned the error 0.02 s after the loop closed, too fast to count, and with the last value
    in the cut as the extreme the swing was a fraction of the cycle's (its trough in air):
    either way the count started afresh at every cycle (bench_loop_watch: seed 3's #44,
    1,019 N peak to peak, alarmed 3.8 s after the onset; seed 202's #52, 1,582 N, 2.2 s).
    Where the force runs against the swing, the extreme of the spell is the swing's turn, found
    at once."""
    cs[CS_O_REOPEN] = 2.0   # the swing under way held a spell (_turn: no pace asked of it)
    if (cs[CS_O_DIR] > 0.0 and rate > 0.0) or (cs[CS_O_DIR] < 0.0 and rate < 0.0):
        cs[CS_O_FLOOR] = cs[CS_O_EXT]
        cs[CS_O_EXT] = error
        cs[CS_O_MARK], cs[CS_O_MARK_AT] = error, cs[CS_O_SINCE]


@compiled
def _watch(cp: np.ndarray, cs: np.ndarray, error: float, rate: float) -> None:
    """The oscillation detector, one period of the force error in the cut.

    A limit cycle is a swing of the error that keeps coming back. From one turning point of
    the error to the next (found with a hysteresis of OSC_HYSTERESIS of the swing, so that
    noise turns nothing), ``oscillation_swings`` swings in a row (:func:`_turn`) raise the
    alarm. A depth step's transient gives two (its rise and its return) and then dies away.
    """
    if cp[C_OSC_SWING] <= 0.0:
        return
    if cs[CS_O_DIR] == 0.0:
        cs[CS_O_DIR], cs[CS_O_EXT], cs[CS_O_LAST] = 1.0, error, error
        cs[CS_O_SWING], cs[CS_O_COUNT], cs[CS_O_SINCE] = 0.0, 0.0, 0.0
        cs[CS_O_SWING_BEFORE], cs[CS_O_PAIRED] = 0.0, 1.0
        cs[CS_O_HSUM], cs[CS_O_CSUM], cs[CS_O_CTIME] = 0.0, 0.0, 0.0
        cs[CS_O_HALF_LAST], cs[CS_O_HALF_BEFORE] = 0.0, 0.0
        cs[CS_O_MARK], cs[CS_O_MARK_AT], cs[CS_O_STALL] = error, 0.0, 0.0
        cs[CS_O_ONSET], cs[CS_O_REOPEN], cs[CS_O_FLOOR] = 0.0, 0.0, math.nan
        cs[CS_O_WIGGLE], cs[CS_O_SPELLED] = 0.0, 0.0
        cs[CS_O_SPELL_S], cs[CS_O_OPENED], cs[CS_O_NET_LAST], cs[CS_O_NET_BEFORE] = (
            0.0, 0.0, 0.0, 0.0)
        return
    if cs[CS_O_REOPEN] == 1.0:
        _reopen(cs, error, rate)
    h = OSC_HYSTERESIS * cp[C_OSC_SWING]
    cs[CS_O_AGE] += cp[C_PERIOD]
    rising = cs[CS_O_DIR] > 0.0
    cs[CS_O_SINCE] += cp[C_PERIOD]
    if (rising and error > cs[CS_O_EXT]) or (not rising and error < cs[CS_O_EXT]):
        cs[CS_O_EXT] = error
        if abs(error - cs[CS_O_MARK]) >= h:   # got on by the hysteresis: no stall
            cs[CS_O_STALL] = pymax(cs[CS_O_STALL], cs[CS_O_SINCE] - cs[CS_O_MARK_AT])
            cs[CS_O_MARK], cs[CS_O_MARK_AT] = error, cs[CS_O_SINCE]
    elif (rising and error < cs[CS_O_EXT] - h) or (not rising and error > cs[CS_O_EXT] + h):
        extreme = cs[CS_O_EXT]
        if math.isfinite(cs[CS_O_FLOOR]):   # the spell's extreme, where further (_reopen)
            extreme = _further(cs[CS_O_DIR], extreme, cs[CS_O_FLOOR])
            cs[CS_O_FLOOR] = math.nan
        _turn(cp, cs, extreme)
        cs[CS_O_EXT], cs[CS_O_DIR] = error, -cs[CS_O_DIR]
        cs[CS_O_MARK], cs[CS_O_MARK_AT], cs[CS_O_STALL] = error, cs[CS_O_SINCE], 0.0
    if cs[CS_O_COUNT] >= cp[C_OSC_COUNT]:
        if cs[CS_O_ALARM] == 0.0:
            _alarm(cp, cs, error)
        else:
            _recycle(cp, cs)
        cs[CS_O_COUNT] = 0.0   # watched afresh (the swings that raised the alarm count once)


@compiled
def _recycle(cp: np.ndarray, cs: np.ndarray) -> None:
    """The detune reaction's own loop cycles (the detector counted ``oscillation_swings``
    swings under it): its crossover halved. Where that cycle is slower than
    REACTION_HALF_RATIO times the alarmed one, the alarmed cycle was not the loop's: the
    crossover at most the reaction's cycle's frequency over RECYCLE_RATIO, that cycle's
    half-period over RECYCLE_RATIO the alarmed one's from now on (the ceiling of
    :func:`_quicken` with it), the level from the reaction's cycle's mean. Under the law on
    the measured feed (:func:`_by_feed`) a cycle no slower than FEED_CYCLE_RATIO times the
    alarmed one is the law's own: it reads the cut through a lag of the cycle's half-period,
    twice the last where it had one."""
    if int(cp[C_OSC_REACTION]) != DETUNE:
        return
    half = cs[CS_O_HALVES] / cs[CS_O_COUNT]
    if cs[CS_O_BY_FEED] != 0.0:
        if half <= FEED_CYCLE_RATIO * cs[CS_O_HALF]:
            cs[CS_O_CUT_S] = pymax(2.0 * cs[CS_O_CUT_S], half)
        return
    cs[CS_O_CROSSOVER] *= 0.5
    if half > REACTION_HALF_RATIO * cs[CS_O_HALF]:
        cs[CS_O_CROSSOVER] = pymin(cs[CS_O_CROSSOVER], math.pi / (RECYCLE_RATIO * half))
        cs[CS_O_HALF] = pymax(cs[CS_O_HALF], half / RECYCLE_RATIO)
        cs[CS_O_TOP] = pymin(cs[CS_O_TOP], math.pi / (FASTEST_RATIO * cs[CS_O_HALF]))
        cs[CS_O_HOLD] = clip(cp, cs[CS_O_CSUM] / cs[CS_O_CTIME])


@compiled
def _log_share(cp: np.ndarray, error: float) -> float:
    """ln(F / F_ref), the force taken at least LOG_FLOOR of the reference."""
    return math.log(pymax(error + cp[C_REF], LOG_FLOOR * cp[C_REF]) / cp[C_REF])


@compiled
def _quicken(cp: np.ndarray, cs: np.ndarray, share: float) -> None:
    """The detune reaction's crossover raised where the loop is sluggish: an excursion of the
    log error ``share`` beyond TAIL_HIGH that comes back to TAIL_LOW without changing sign
    (no overshoot) slower than TAIL_RATE_PER_S (its time, ln(TAIL_HIGH / TAIL_LOW) over the
    rate) raises the crossover by the ratio of the two, up to w_u / FASTEST_RATIO."""
    size, sign = abs(share), 1.0 if share > 0.0 else -1.0
    if size >= TAIL_HIGH:
        cs[CS_O_TAIL], cs[CS_O_TAIL_SIGN] = 0.0, sign
    elif cs[CS_O_TAIL] >= 0.0:
        if sign != cs[CS_O_TAIL_SIGN]:   # overshot: not sluggish
            cs[CS_O_TAIL] = -1.0
            return
        cs[CS_O_TAIL] += cp[C_PERIOD]
        if size <= TAIL_LOW:
            rate = math.log(TAIL_HIGH / TAIL_LOW) / cs[CS_O_TAIL]
            if rate < TAIL_RATE_PER_S:
                cs[CS_O_CROSSOVER] = pymax(cs[CS_O_CROSSOVER], pymin(
                    cs[CS_O_CROSSOVER] * TAIL_RATE_PER_S / rate,
                    cs[CS_O_TOP]))
            cs[CS_O_TAIL] = -1.0


@compiled
def _feed_forward(cp: np.ndarray, cs: np.ndarray, share: float, log_rate: float) -> bool:
    """The detune reaction's answer to a depth step down (STEP_*): whether it sets the level
    this period (the PI law rests), ``share`` being ln(F / F_ref) and ``log_rate`` d ln F /
    dt."""
    half, dt = cs[CS_O_HALF], cp[C_PERIOD]
    if cs[CS_O_FF_PHASE] == FF_WATCH:
        if abs(share) <= STEP_CALM:
            cs[CS_O_FF_TIME] += dt
            cs[CS_O_FF_SHARE] += (share - cs[CS_O_FF_SHARE]) * pymin(dt / STEP_CALM_MEAN_S, 1.0)
            cs[CS_O_FF_LEVEL] = cs[CS_O_HOLD]
            return False
        settled = cs[CS_O_FF_TIME] >= STEP_CALM_HALVES * half and cs[CS_O_FF_LEVEL] > 0.0
        if settled and log_rate >= STEP_RATE_PER_S and share > cs[CS_O_FF_SHARE]:
            cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME], cs[CS_O_FF_NEAR] = FF_RISE, 0.0, 0.0
            cs[CS_O_FF_FAR] = 0.0
            return False
        if not settled or -log_rate < STEP_RATE_PER_S or share > cs[CS_O_FF_SHARE]:
            cs[CS_O_FF_TIME], cs[CS_O_FF_SHARE] = 0.0, share
            return False
        cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME] = FF_STEP, 0.0
        cs[CS_O_FF_NEAR], cs[CS_O_FF_FAR] = 0.0, 0.0
    if cs[CS_O_FF_PHASE] == FF_RISE:
        return False
    cs[CS_O_FF_TIME] += dt
    cs[CS_O_COUNT] = 0.0   # the step's swings are the program's, not the reaction cycling
    if share > STEP_CALM or (cs[CS_O_FF_TIME] > STEP_WINDOW_HALVES * half
                             and abs(share) <= TAIL_LOW):
        cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME], cs[CS_O_FF_SHARE] = FF_WATCH, 0.0, share
        return False
    g, lag = cp[C_EXPONENT], pymax(STEP_LAG_HALVES * half / 2.0, dt)
    moved = math.log(cs[CS_O_HOLD] / cs[CS_O_FF_LEVEL])
    cs[CS_O_FF_NEAR] += (moved - cs[CS_O_FF_NEAR]) * pymin(dt / lag, 1.0)
    cs[CS_O_FF_FAR] += (cs[CS_O_FF_NEAR] - cs[CS_O_FF_FAR]) * pymin(dt / lag, 1.0)
    jump = share - cs[CS_O_FF_SHARE] - g * cs[CS_O_FF_FAR]
    cs[CS_O_HOLD] = clip(cp, cs[CS_O_FF_LEVEL] * math.exp(-jump / g))
    return True


@compiled
def _proportional(cp: np.ndarray, cs: np.ndarray, share: float, change: float) -> float:
    """The detune reaction's proportional move of ln u this period, ``share`` being
    ln(F / F_ref) and ``change`` its change since the period before: DETUNE_P of the change,
    and at the peak of a slow depth step up (RISE_*: FF_NEAR its rise so far, FF_FAR 1 once
    past the peak) RISE_KEEP of its rise, once. The step up ends where the force is back
    within TAIL_LOW."""
    if cs[CS_O_FF_PHASE] != FF_RISE:
        return DETUNE_P * change
    cs[CS_O_COUNT] = 0.0   # the step's swings are the program's, not the reaction cycling
    rise = share - cs[CS_O_FF_SHARE]
    if share <= TAIL_LOW:   # back (or overshot): the PI law's alone again
        cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME], cs[CS_O_FF_SHARE] = FF_WATCH, 0.0, share
        return DETUNE_P * change
    cs[CS_O_FF_TIME] += cp[C_PERIOD]
    if rise >= cs[CS_O_FF_NEAR]:
        cs[CS_O_FF_NEAR] = rise
        return DETUNE_P * change
    keep = cs[CS_O_FF_FAR] == 0.0 and cs[CS_O_FF_TIME] >= RISE_HALVES * cs[CS_O_HALF]
    cs[CS_O_FF_FAR] = 1.0
    return DETUNE_P * change + (RISE_KEEP * cs[CS_O_FF_NEAR] if keep else 0.0)


@compiled
def _model_feed(cp: np.ndarray, cs: np.ndarray) -> bool:
    """The detune reaction's model of the force's lag behind the axis feed the DAQ measured
    (REACTION_LAG_S on the log of its share, floored at REACTION_FEED_FLOOR), one period on;
    whether the reaction's law runs on it (:func:`_by_feed`): not where no feed is measured,
    nor ever again once it was lost (a feed that comes and goes is no model's input)."""
    feed = cs[CS_O_FEED]
    if cs[CS_O_BY_FEED] == 0.0 or not math.isfinite(feed):
        cs[CS_O_BY_FEED] = 0.0
        return False
    log_feed = math.log(pymax(feed, REACTION_FEED_FLOOR))
    if not math.isfinite(cs[CS_O_MODEL_FEED]):
        cs[CS_O_MODEL_FEED] = log_feed
    cs[CS_O_MODEL_FEED] += (log_feed - cs[CS_O_MODEL_FEED]) * (
        1.0 - math.exp(-cp[C_PERIOD] / REACTION_LAG_S))
    return True


@compiled
def _by_feed(cp: np.ndarray, cs: np.ndarray, share: float) -> float:
    """The detune reaction's level from the measured feed (REACTION_*), ``share`` being
    ln(F / F_ref): the cut's own ln(K d / F_ref), the share less g times the model's lagged
    log feed (itself lagged where the law cycled: FEED_CYCLE_RATIO), and the level that brings
    the force to the reference, exp(-that / g), g at REACTION_EXPONENT_SHARE of the exponent
    the laws assume; a rise through FEED_RISE_HALVES of the alarmed half-period. Out of the
    cut the gate sets the feed and the level held stands."""
    if cs[CS_ENGAGED] != 0.0:
        g = REACTION_EXPONENT_SHARE * cp[C_EXPONENT]
        cut = share - g * cs[CS_O_MODEL_FEED]
        if not math.isfinite(cs[CS_O_CUT]) or cs[CS_O_CUT_S] <= 0.0:
            cs[CS_O_CUT] = cut
        else:
            cs[CS_O_CUT] += (cut - cs[CS_O_CUT]) * (1.0 - math.exp(-cp[C_PERIOD] / cs[CS_O_CUT_S]))
        level, held = clip(cp, 100.0 * math.exp(-cs[CS_O_CUT] / g)), pymax(cs[CS_O_HOLD], 1.0)
        if level > held:   # a rise through FEED_RISE_HALVES of the alarmed half-period
            level = held * (level / held) ** (
                1.0 - math.exp(-cp[C_PERIOD] / (FEED_RISE_HALVES * cs[CS_O_HALF])))
        cs[CS_O_HOLD] = clip(cp, level)
    return cs[CS_O_HOLD]


@compiled
def _react(cp: np.ndarray, cs: np.ndarray, error: float, rate: float) -> float:
    """The reaction's request while the alarm holds: the detune reaction's level from the
    measured feed (:func:`_by_feed`) or, where none is measured, its PI law on the log of
    the relative feed (DETUNE_RATIO, DETUNE_P), kept inside the table; or the held level. After
    the gate has set the feed, the law waits on the gate's level until the force has settled
    there, and starts from the level that force implies."""
    if int(cp[C_OSC_REACTION]) == DETUNE:
        force = error + cp[C_REF]
        share = _log_share(cp, error)
        change, cs[CS_O_LOG_FORCE] = share - cs[CS_O_LOG_FORCE], share
        by_feed = _model_feed(cp, cs)
        if cs[CS_O_WAIT] != 0.0:
            cs[CS_O_FF_PHASE], cs[CS_O_FF_TIME], cs[CS_O_FF_SHARE] = FF_WATCH, 0.0, 0.0
            if force >= ENTRY_FORCE_SHARE * cp[C_REF] and abs(rate) <= ENTRY_RATE_PER_S * force:
                cs[CS_O_HOLD], cs[CS_O_WAIT] = _implied(cp, cs[CS_O_HOLD], force), 0.0
            return cs[CS_O_HOLD]
        if by_feed:
            return _by_feed(cp, cs, share)
        _quicken(cp, cs, share)
        if _feed_forward(cp, cs, share, rate / pymax(force, LOG_FLOOR * cp[C_REF])):
            return cs[CS_O_HOLD]
        step = cs[CS_O_CROSSOVER] * cp[C_PERIOD] * share + _proportional(cp, cs, share, change)
        cs[CS_O_HOLD] = clip(cp, cs[CS_O_HOLD] * math.exp(-pymin(pymax(step, -0.5), 0.5)))
    return cs[CS_O_HOLD]


@compiled
def _left_cut(cs: np.ndarray) -> None:
    """The first period after the tool left the cut: where the axis still fed at
    EXIT_FEED_SHARE of the loop's level or more, the program took it out: the count starts
    afresh, and the swing under way (the fall to the air) ends as a kick's rise out of a calm
    spell (its stall taken as endless). Where the feed had stopped (or none was measured),
    the swing goes on through the spell. Under the alarm the reaction's own count goes on
    (:func:`_recycle`)."""
    if cs[CS_O_ALARM] == 0.0 and cs[CS_O_FEED] >= EXIT_FEED_SHARE * cs[CS_O_LEVEL]:
        cs[CS_O_COUNT], cs[CS_O_STALL] = 0.0, math.inf


@compiled
def _out_of_cut(cp: np.ndarray, cs: np.ndarray, error: float) -> None:
    """A period out of the cut, or with the loop open (the PMC holds a level of its own). The
    detector pauses: a cycle whose troughs carry the force under the gate's exit threshold
    (``exit_force_n``) leaves the cut at each of them, and the swing goes on from where the
    force left to where it comes back. Once no turn has come
    for OSC_HALF_MAX_S (a swing that slow counts for nothing) the detector starts afresh at
    the next entry. The alarm and its reaction hold until the run ends or the tool changes
    (:func:`controller_tool`): a loop that cycled cycles again at the next entry, and finding
    it again would cost another ``oscillation_swings`` swings."""
    cs[CS_O_SINCE] += cp[C_PERIOD]
    cs[CS_O_SPELL_S] += cp[C_PERIOD]
    cs[CS_O_MARK_AT] += cp[C_PERIOD]   # no stall of the error in the cut
    cs[CS_O_REOPEN] = 1.0
    # the swing's extreme goes on (_reopen): in air the force is the estimator's zero
    cs[CS_O_EXT] = _further(cs[CS_O_DIR], cs[CS_O_EXT], error)
    if cs[CS_O_SINCE] > OSC_HALF_MAX_S:
        cs[CS_O_DIR], cs[CS_O_COUNT] = 0.0, 0.0


@compiled
def _moving(cp: np.ndarray, levels: np.ndarray) -> float:
    """The table's lowest level that moves the axis (a hold at 0 % would stop the tool in the
    cut)."""
    lowest = cp[C_MAX]
    for j in range(levels.size):
        if levels[j] > 0.0:
            lowest = pymin(lowest, levels[j])
    return lowest


@compiled
def _fall(cp: np.ndarray, cs: np.ndarray, levels: np.ndarray, error: float, rate: float,
          allowed: bool) -> int:
    """Whether the loop holds its level through the tool's exit where the gate has not seen it
    yet (FALL_RATE_PER_S's text): FALL_HELD, FALL_PENDING while the fall is not yet sure
    (the request is not to rise meanwhile), or FALL_NONE; never where not ``allowed``."""
    ref = cp[C_REF]
    heading = force_heading(cp, error + ref, rate)   # where the force goes (FALL_RATE_PER_S)
    if cs[CS_ENGAGED] == 0.0:
        cs[CS_FALL], cs[CS_FALL_BASE], cs[CS_FALL_S] = 0.0, 0.0, 0.0
        return FALL_NONE
    if cs[CS_O_OPEN] != 0.0 or not allowed:
        cs[CS_FALL], cs[CS_FALL_S] = 0.0, 0.0
        return FALL_NONE
    if cs[CS_FALL] == 0.0:
        feed = cs[CS_O_FEED]
        if abs(error) <= FALL_NEAR_SHARE * ref and abs(rate) <= FALL_CALM_RATE_PER_S * ref \
                and feed > 0.0:
            base, level = cs[CS_FALL_BASE], 100.0 * feed
            cs[CS_FALL_BASE] = level if base <= 0.0 else _mean(base, level, cp,
                                                               FALL_BASE_MEAN_S)
        if not (error < 0.0 and rate < -FALL_RATE_PER_S * ref
                and heading < FALL_HEADING_SHARE * ref
                and feed >= FALL_FEED_SHARE * cs[CS_FALL_FEED]
                and feed >= EXIT_FEED_SHARE * cs[CS_O_LEVEL] and feed > 0.0):
            cs[CS_FALL_S] = 0.0
            return FALL_NONE
        cs[CS_FALL_S] += cp[C_PERIOD]   # so far for FALL_SURE_S
        if cs[CS_FALL_S] < FALL_SURE_S - 1e-9:
            return FALL_PENDING
        # never above the level sent: the hold does not raise the feed
        level = cs[CS_FALL_BASE] if cs[CS_FALL_BASE] > 0.0 else cs[CS_FALL_ENTRY]
        cap = cs[CS_HELD] if level <= 0.0 else pymin(cs[CS_HELD],
                                                      pymax(level, _moving(cp, levels)))
        cs[CS_FALL], cs[CS_FALL_CAP] = 1.0, clip(cp, cap)
        cs[CS_FALL_S], cs[CS_FALL_CALM] = 0.0, 0.0
        return FALL_HELD
    cs[CS_FALL_S] += cp[C_PERIOD]
    # the force heads for a level in the cut (a smaller depth, not the exit; or the tool
    # back in after a groove), and no longer rises fast
    calm = heading >= FALL_STAYS_SHARE * ref and rate <= FALL_CALM_RATE_PER_S * ref
    cs[CS_FALL_CALM] = cs[CS_FALL_CALM] + cp[C_PERIOD] if calm else 0.0
    if error >= 0.0 or cs[CS_FALL_CALM] >= FALL_CALM_S - 1e-9 \
            or cs[CS_FALL_S] >= FALL_HOLD_MAX_S - 1e-9:
        cs[CS_FALL], cs[CS_FALL_S] = 0.0, 0.0
        return FALL_NONE
    return FALL_HELD


@compiled
def controller_update(cp: np.ndarray, cs: np.ndarray, levels: np.ndarray, force: float,
                      rate: float, out: np.ndarray) -> None:
    """One control period: the law, the guard on its state, the error-feedback quantiser,
    the reachability flag, the oscillation alarm with its reaction and the drift monitor
    (:mod:`.drift`, which sets no feed: it names drifts, asks the estimator to take off a
    friction drift it reads, :func:`.drift.drift_correction`, and where ``drift_adopt_model``
    is on hands a lag drift it names anew to the law's ``adopt``, an oscillation alarm that
    holds let go at the first: ADOPT_SETTLE), and the hold through the tool's exit where the
    gate has not seen it yet (:func:`_fall`); out = (pct, error, s, reachable, oscillating,
    drift, drift's size)."""
    error = force - cp[C_REF]
    out[OUT_OSC] = cs[CS_O_ALARM]
    monitor = cs[CS_DRIFT:CS_LAW]
    was = monitor[DS_ALARM]
    drift_step(cp[C_DRIFT:C_LAW], monitor, force, cs[CS_ENGAGED] != 0.0, cs[CS_HELD])
    cause, size = monitor[DS_ALARM], monitor[DS_ALARM_SIZE]
    out[OUT_DRIFT], out[OUT_DRIFT_SIZE] = cause, size
    if cause != was and int(cause) in (DEAD_TIME, SERVO) and cp[C_DRIFT + D_ADOPT] != 0.0 \
            and law_adopt(int(cp[C_KIND]), cp, cs, int(cause), size):
        # a lag drift newly named: the law predicts with that member of the bank from now on,
        # another loop, whose swings the oscillation detector counts afresh once the switch's
        # own transient is over (ADOPT_SETTLE). A new size of the same cause is not taken: the
        # monitor still compares the machine with the identified model, while the loop it
        # watches now runs on the adopted one, moves the override less, and tells the members
        # apart less well (seed 15's #9, servo x1.39: named x1.44, then x2.49, which taken too
        # made the loop cycle: 45.9 N steady against 14.9 N with none taken)
        first = monitor[DS_ADOPTED] == NONE
        monitor[DS_ADOPTED], monitor[DS_ADOPTED_SIZE] = cause, size
        if cs[CS_O_ALARM] == 0.0 or first:
            # a ring the alarm caught before the drift was named: the reaction lets go, once
            # (ADOPT_SETTLE's text)
            cs[CS_O_ALARM] = 0.0
            cs[CS_O_DIR], cs[CS_O_COUNT] = 0.0, 0.0
            cs[CS_O_AGE] = -ADOPT_SETTLE * cp[C_DRIFT + D_MEMORY]
    if not (math.isfinite(force) and math.isfinite(rate)):
        _recover(cp, cs, error, out)
        return
    kind, reaction = int(cp[C_KIND]), int(cp[C_OSC_REACTION])
    # the hold through an exit the gate has not seen (_fall); not under a reaction, which
    # sets the feed itself
    fall = _fall(cp, cs, levels, error, rate,
                 cs[CS_O_ALARM] == 0.0 or reaction == NO_REACTION)
    held = fall == FALL_HELD
    if cs[CS_ENGAGED] != 0.0 and cs[CS_O_OPEN] == 0.0 and not held:
        _watch(cp, cs, error, rate)
        out[OUT_OSC] = cs[CS_O_ALARM]
    else:
        # the spell's first period: out of the cut, or held through the exit
        if (cs[CS_ENGAGED] == 0.0 or held) and cs[CS_O_REOPEN] != 1.0:
            _left_cut(cs)
        _out_of_cut(cp, cs, error)
    reacting = cs[CS_O_ALARM] != 0.0 and reaction != NO_REACTION
    if held:
        # the level held, shaped like the reaction's (the law is put at rest on it below)
        out[OUT_PCT], out[OUT_ERR], out[OUT_S] = cs[CS_FALL_CAP], error, 0.0
    elif reacting:
        # the reaction sets the feed; the law is kept at rest on the level held
        law_reset(kind, cp, cs)
        out[OUT_PCT], out[OUT_ERR], out[OUT_S] = _react(cp, cs, error, rate), error, 0.0
    else:
        law_step(kind, cp, cs, force, rate, out)
    if not (math.isfinite(out[OUT_PCT]) and math.isfinite(out[OUT_S])
            and law_finite(kind, cp, cs)):
        _recover(cp, cs, error, out)
        return
    request = out[OUT_PCT]
    if fall == FALL_PENDING:   # no rise on a fall that may be the tool's exit
        request = out[OUT_PCT] = pymin(request, cs[CS_HELD])
    continuous = cp[C_CONT] != 0.0
    if continuous or (cp[C_EF] == 0.0 and not (reacting or held)):   # theirs: shaped
        sent = request
    else:
        wanted = clip(cp, request + cs[CS_CARRY])
        sent = quantise(levels, continuous, wanted)
        cs[CS_CARRY] = pymin(pymax(request + cs[CS_CARRY] - sent, -cp[C_GAP]), cp[C_GAP])
    law_sent(kind, cp, cs, quantise(levels, continuous, sent))
    cs[CS_HELD] = sent
    if held:   # the law at rest on the level sent, as in air
        law_reset(kind, cp, cs)
    cs[CS_O_HSUM] += sent * cp[C_PERIOD]
    out[OUT_REACH] = _track_reach(cp, cs, request, out[OUT_ERR])
    out[OUT_PCT] = sent


@compiled
def controller_applied(cp: np.ndarray, cs: np.ndarray, applied: float, engaged: bool,
                       reason: int) -> None:
    """The override the PMC applied after the controller's request (after the quantiser and
    the gate: FeedOverride's ``applied_pct``, ``engaged`` and ``reason``). Where the request did
    not go through as asked (any reason but :data:`REASON_NORMAL`: disarmed, a hold, the air-cut
    or entry feed, the dial, the rise limit), the law starts afresh from the applied level each
    period: conditional integration, the anti-windup of Astrom & Hagglund (PID Controllers,
    1995, Sec. 3.5), so that no law winds up against a feed it does not set and each entry into
    the cut starts from the feed the tool meets the work with (the oscillation reaction's
    level too)."""
    cs[CS_ENGAGED] = 1.0 if engaged else 0.0
    cs[CS_O_OPEN] = 0.0 if reason in (REASON_NORMAL, REASON_RISE_LIMIT, REASON_FEED_FLOOR) \
        else 1.0
    if reason not in (REASON_NORMAL, REASON_RISE_LIMIT, REASON_FEED_FLOOR, REASON_AIR_CUT):
        cs[CS_O_OPENED] = 1.0
    if engaged and cs[CS_O_OPEN] == 0.0 and math.isfinite(applied):   # the loop's level
        cs[CS_O_LEVEL] = _mean(cs[CS_O_LEVEL], clip(cp, applied) / 100.0, cp, LEVEL_MEAN_S)
    drift_applied(cs[CS_DRIFT:CS_LAW], applied)
    if reason == REASON_AIR_CUT and math.isfinite(applied):   # the hold's (_fall)
        cs[CS_FALL_ENTRY] = clip(cp, applied)
    # the force's rise that a law's model may follow (CS_ENTERING): at the gate's entry feed,
    # and at the end of a hold through an exit the gate did not see (_fall: the law rests)
    cs[CS_ENTERING] = 1.0 if engaged and (reason == REASON_AIR_CUT or cs[CS_FALL] != 0.0) \
        else 0.0
    if reason != REASON_NORMAL and math.isfinite(applied):
        # the oscillation detector's sum of the levels over the swing: the level applied,
        # not the law's (a law held at the entry feed asks for 150 %)
        cs[CS_O_HSUM] += (clip(cp, applied) - cs[CS_HELD]) * cp[C_PERIOD]
        cs[CS_HELD] = clip(cp, applied)
        cs[CS_CARRY] = 0.0
        law_reset(int(cp[C_KIND]), cp, cs)
    if (reason != REASON_NORMAL or not engaged) and math.isfinite(applied) \
            and int(cp[C_OSC_REACTION]) == DETUNE:   # the reaction's integral, likewise
        cs[CS_O_HOLD], cs[CS_O_WAIT] = clip(cp, applied), 1.0


@entry('void(float64[::1], float64[::1], float64, boolean, int64)')
def control_applied(cp: Arr, cs: Arr, applied: float, engaged: bool, reason: int) -> None:
    """:func:`controller_applied` from Python (the controller node, the per-block chain)."""
    controller_applied(cp, cs, applied, engaged, reason)


@entry('void(float64[::1], float64[::1])')
def controller_start(cp: Arr, cs: Arr) -> None:
    """A controller's first state, from the held request (``CS_HELD``) and its parameters."""
    law_reset(int(cp[C_KIND]), cp, cs)


@entry('void(float64[::1], float64[::1], float64[::1], float64, float64, float64[::1])')
def control_step(cp: Arr, cs: Arr, levels: Arr, force: float, rate: float, out: Arr) -> None:
    """:func:`controller_update` from Python (the nodes, replay)."""
    controller_update(cp, cs, levels, force, rate, out)


@compiled
def controller_tool(tools: np.ndarray, cp: np.ndarray, cs: np.ndarray, number: float) -> int:
    """The machine's tool input says tool ``number``: its row of ``tools`` (the number, then
    the parameters ``cp`` of its settings) becomes the parameters, the spindle speed in use
    kept; returns the row, -1 where the table has none (the parameters stay). A tool changes in
    air: the law starts afresh from the request held, as at an entry (the anti-windup of
    :func:`controller_applied`), the quantiser's carry and the reachability clock cleared. The
    oscillation alarm ends: another tool is another loop, watched afresh; so does the drift
    alarm (:func:`.drift.drift_tool`): the tool's own model is watched from its start, and
    the law predicts with it (``adopt`` with no cause)."""
    row = table_row(tools, number)
    if row < 0:
        return row
    rpm = cp[C_RPM]
    for j in range(cp.size):
        cp[j] = tools[row, j + 1]
    spindle_speed(cp, rpm)
    cs[CS_CARRY], cs[CS_PINNED], cs[CS_SIDE] = 0.0, 0.0, 0.0
    cs[CS_O_ALARM], cs[CS_O_DIR], cs[CS_O_COUNT] = 0.0, 0.0, 0.0
    drift_tool(cs[CS_DRIFT:CS_LAW])
    law_adopt(int(cp[C_KIND]), cp, cs, NONE, 0.0)   # the tool's commissioned model
    law_reset(int(cp[C_KIND]), cp, cs)
    return row


@compiled
def controller_feed(cp: np.ndarray, cs: np.ndarray, feed_mm_min: float) -> None:
    """The axis feed the DAQ measured over the block the coming update answers, its mean
    [mm/min]: the drift monitor's feed test (:func:`.drift.drift_feed`) and the oscillation
    detector's test of the tool's exits (EXIT_FEED_SHARE), against the 100 % override's feed
    rate at the spindle speed in use (``spindle_speed`` first)."""
    drift_feed(cs[CS_DRIFT:CS_LAW], feed_mm_min, cp[C_FEED_RATE], cp[C_PERIOD])
    # the oscillation detector's, whatever the drift monitor takes (_left_cut)
    cs[CS_O_FEED] = feed_mm_min / cp[C_FEED_RATE] if cp[C_FEED_RATE] > 0.0 else math.nan
    if math.isfinite(cs[CS_O_FEED]):   # the hold's (_fall)
        cs[CS_FALL_FEED] = _mean(cs[CS_FALL_FEED], cs[CS_O_FEED], cp, FALL_FEED_MEAN_S)


@entry('void(float64[::1], float64[::1], float64)')
def control_feed(cp: Arr, cs: Arr, feed_mm_min: float) -> None:
    """:func:`controller_feed` from Python (the controller node, the per-block chain)."""
    controller_feed(cp, cs, feed_mm_min)


@compiled
def controller_rezeroed(cp: np.ndarray, cs: np.ndarray, scale: float) -> None:
    """The estimator re-zeroed the friction in air to ``scale`` x calibrated: the drift
    monitor's measurement of the friction (:func:`.drift.drift_rezeroed`)."""
    drift_rezeroed(cp[C_DRIFT:C_LAW], cs[CS_DRIFT:CS_LAW], scale)


@entry('void(float64[::1], float64[::1], float64)')
def control_rezeroed(cp: Arr, cs: Arr, scale: float) -> None:
    """:func:`controller_rezeroed` from Python (the controller node, the per-block chain)."""
    controller_rezeroed(cp, cs, scale)


@entry('int64(float64[:, ::1], float64[::1], float64[::1], float64)')
def control_tool(tools: Arr, cp: Arr, cs: Arr, number: float) -> int:
    """:func:`controller_tool` from Python (the controller node, the per-block chain)."""
    return controller_tool(tools, cp, cs, number)
