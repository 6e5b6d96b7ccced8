"""The lathe as a plant: PMC, feed servo, cutting process and feed-drive currents.

Signal chain, sampled at the DAQ rate and stepped one control block at a time::

    override [%] -> PMC dead time -> v_c = override * f_prog * N [mm/min]
      -> CNC servo (Park Eq. 2, first order; or Hwang & Chen Eq. 1, second order) -> v_a
      -> cutting process F = k d (v_a / N)^g / (1 + tau_c s)   (Park Eq. 1; Hwang & Chen Eq. 3)
      -> q-axis current (Park Eq. 26) + friction (Park Eq. 25) -> u, v phase currents + noise

The linear process of Park (``g = 1``, ``k = K_s``) and the power law of Hwang & Chen
(``g = 0.95``, ``k = k_f``) are one model. Linear blocks are discretised exactly (zero-order hold)
once and run as direct-form-II-transposed filters, their state carried from block to block.
The arithmetic is written once, compiled, in :mod:`turning_force.core.plant.lathe`
(:class:`~turning_force.core.plant.lathe.LathePlant` and the compiled core loop both run it); this
module holds the plant's settings and what it gives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core import shared
from turning_force.core.plant.drive import CurrentBlock, FeedDriveSettings
from turning_force.core.pmc.overrides import override_table
from turning_force.core.pmc.shopfloor import NO_INPUTS, InputValues
from turning_force.core.settings import INT64_MAX, setting

__all__ = ['DepthProfile', 'Dynamometer', 'PlantBlock', 'PlantSettings']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PlantSettings(FeedDriveSettings):
    """The simulated lathe (``lathe_sim`` parameters); the drive fields are the machine's
    true friction and current map."""

    SECTION = 'lathe_sim'

    seed: int = setting(1, 'Seed of the sensor and process noise', low=0, unit='-', high=INT64_MAX)
    control_period_s: float = shared.control_period_s()
    override_table: str = override_table()
    approach_override_pct: float = setting(
        100.0, 'The override the axis approached the work at, before t = 0 (the PMC level it '
        'feeds at when the run starts); not given in a file: the level the PMC holds in air, '
        'the entry feed (pmc_bridge.air_cut_override_pct) where the bridge is armed and has '
        'one, else force_controller.initial_override_pct', '%', low=0.0, high=1000.0)
    sample_rate_hz: float = setting(1000.0, 'DAQ sample rate of the phase currents', 'Hz',
                                    low=10.0, high=100000.0)
    spindle_speed_rpm: float = shared.spindle_speed_rpm()
    programmed_feed_mm_rev: float = shared.programmed_feed_mm_rev()
    specific_cutting_force_n_mm2: float = setting(
        2200.0, 'Specific cutting force K_s (Park Eq. 1) or k_f (Hwang & Chen Eq. 3)',
        'N/mm^2', low=0.0, low_open=True, high=20000.0,
        cite='Park 1998, Eq. 1; Hwang & Chen 1990, Eq. 3')
    cutting_exponent: float = setting(1.0, 'Feed exponent g of F = k d f^g (1: linear, Park)',
                                      low=0.1, high=1.5, unit='-',
                                      cite='Hwang & Chen 1990, Eq. 3 (g = 0.95)')
    cutting_time_constant_s: float = setting(
        0.05, 'Cutting-process time constant tau_c (Park Eq. 1); 0 for a static process', 's',
        low=0.0, high=10.0, cite='Park 1998, Eq. 1')
    servo_model: str = setting('first_order', 'CNC feed-servo model',
                               choices=('first_order', 'second_order'))
    servo_time_constant_s: float = setting(0.17, 'First-order servo time constant tau_s '
                                           '(Park Eq. 2)', 's', low=0.0, low_open=True, high=10.0,
                                           cite='Park 1998, Eq. 2')
    servo_natural_freq_rad_s: float = setting(60.0, 'Second-order servo natural frequency w_n '
                                              '(Hwang & Chen Eq. 1)', 'rad/s', low=0.0,
                                              low_open=True, high=1e4,
                                              cite='Hwang & Chen 1990, Eq. 1')
    servo_damping: float = setting(0.7, 'Second-order servo damping ratio xi', low=0.0,
                                   low_open=True, high=10.0, unit='-',
                                   cite='Hwang & Chen 1990, Eq. 1')
    pmc_dead_time_s: float = setting(0.0, 'PMC dead time before the servo sees a new override '
                                     '(Kim: 0.08 s)', 's', low=0.0, high=2.0, cite='Kim, Eqs. 1-2')
    depth_times_s: tuple[float, ...] = setting([0.0, 4.0, 8.0], 'Times of the depth-of-cut '
                                               'break points', 's', low=0.0, high=3600.0)
    depth_mm: tuple[float, ...] = setting([1.0, 2.0, 3.0], 'Depth of cut at each break point',
                                          'mm', low=0.0, high=50.0)
    depth_interpolation: str = setting('step', 'Depth between break points: held (steps) or '
                                       'linear (taper)', choices=('step', 'linear'))
    current_noise_a: float = setting(0.02, 'Standard deviation of the phase-current sensor noise',
                                     'A', low=0.0, high=10.0)
    feed_noise_mm_min: float = setting(0.0, 'Standard deviation of the feed-rate reading the '
                                       'DAQ records (an encoder differentiated)', 'mm/min',
                                       low=0.0, high=1e4)
    force_noise_fraction: float = setting(0.0, 'Cutting-force fluctuation, uniform within '
                                          '+/- this fraction (Hwang & Chen Example 2: 0.01)',
                                          low=0.0, high=0.5, unit='-',
                                          cite='Hwang & Chen 1990, Example 2')
    sensor_fault_start_s: float = setting(0.0, 'Fault injection: the current sensor reads NaN '
                                          'from this time (a broken wire, a DAQ fault)', 's',
                                          low=0.0, high=3600.0)
    sensor_fault_duration_s: float = setting(0.0, 'Fault injection: how long the current '
                                             'sensor reads NaN; 0: no fault', 's', low=0.0,
                                             high=3600.0)
    dynamometer: bool = setting(False, 'Publish force/measured: the force as a table '
                                'dynamometer beside the tool reads it (for calibrate --map)')
    dynamometer_noise_n: float = setting(2.0, "Standard deviation of the dynamometer's reading "
                                         'of one block', 'N', low=0.0, high=1e4)
    program_enable_spans_s: tuple[float, ...] = setting(
        [0.0, 0.0], 'Simulated program-enable input (an M-code relay the part program sets): '
        'set within the [start, end) spans, given as flat pairs; no non-empty span: not wired',
        's', low=0.0, high=3600.0)
    threading_spans_s: tuple[float, ...] = setting(
        [0.0, 0.0], 'Simulated threading input: thread cutting or tapping within the [start, '
        'end) spans, given as flat pairs; no non-empty span: not wired', 's', low=0.0,
        high=3600.0)
    operator_dial_wired: bool = setting(False, "Simulate the operator's override dial "
                                        '(operator_dial_times_s, operator_dial_pct)')
    operator_dial_times_s: tuple[float, ...] = setting(
        [0.0], "Times the simulated operator's dial is turned", 's', low=0.0, high=3600.0)
    operator_dial_pct: tuple[float, ...] = setting(
        [100.0], "The simulated operator's dial from each of operator_dial_times_s on", '%',
        low=0.0, high=1000.0)
    css_surface_speed_m_min: float = setting(
        0.0, 'Constant surface speed (G96) of a facing cut: the spindle speed rises as the '
        'feed axis (the cross slide) takes the diameter down, N = 1000 V / (pi D); 0: the '
        'spindle turns at spindle_speed_rpm', 'm/min', low=0.0, high=2000.0)
    css_start_diameter_mm: float = setting(100.0, 'Constant surface speed: the diameter the '
                                           'facing cut starts at', 'mm', low=0.0,
                                           low_open=True, high=5000.0)
    css_max_spindle_rpm: float = setting(1500.0, 'Constant surface speed: the largest spindle '
                                         'speed the program allows (G50 S)', 'rpm', low=0.0,
                                         low_open=True, high=20000.0)
    tool_wired: bool = setting(False, "Simulate the machine's tool input (machine/tool: the T "
                               'code in use) and a program that changes tools: tool_times_s, '
                               'tool_numbers, and the material each tool cuts')
    tool_times_s: tuple[float, ...] = setting(
        [0.0], 'Times the simulated program changes tool (in air, between cuts)', 's', low=0.0,
        high=3600.0)
    tool_numbers: tuple[int, ...] = setting([1], 'The tool number (T code) from each of '
                                            'tool_times_s on', '-', low=0, high=9999)
    tool_specific_cutting_force_n_mm2: tuple[float, ...] = setting(
        [2200.0], 'The specific cutting force each tool of tool_numbers meets (its insert and '
        'material): specific_cutting_force_n_mm2 from each of tool_times_s on', 'N/mm^2',
        low=0.0, low_open=True, high=20000.0, cite='Park 1998, Eq. 1')
    tool_cutting_exponent: tuple[float, ...] = setting(
        [1.0], 'The feed exponent g each tool of tool_numbers meets: cutting_exponent from each '
        'of tool_times_s on', '-', low=0.1, high=1.5, cite='Hwang & Chen 1990, Eq. 3')
    spindle_speed_wired: bool = setting(True, 'The simulated machine gives its spindle speed '
                                        '(machine/spindle_speed, from the spindle encoder); '
                                        'false: the input unplugged')
    override_cancel_span_s: tuple[float, ...] = setting(
        [0.0, 0.0], 'Fault injection: override cancel (M49) within this [start, end): the feed '
        'at 100 % whatever the PMC is written (a ladder that never copies the override to *FV: '
        'the whole run)', 's', low=0.0, high=3600.0)
    feed_hold_span_s: tuple[float, ...] = setting(
        [0.0, 0.0], 'Fault injection: feed hold within this [start, end): the axis stops', 's',
        low=0.0, high=3600.0)
    dry_run_span_s: tuple[float, ...] = setting(
        [0.0, 0.0], 'Fault injection: dry run within this [start, end): the axis at '
        'dry_run_feed_mm_min whatever the override', 's', low=0.0, high=3600.0)
    dry_run_feed_mm_min: float = setting(1000.0, 'The dry-run feed rate', 'mm/min', low=0.0,
                                         high=1e5)
    pole_pairs: int = setting(4, 'Pole pairs of the feed servo motor', low=1, high=64, unit='-')
    ball_screw_pitch_mm: float = setting(12.0, 'Ball-screw pitch (motor on the screw)', 'mm',
                                         low=0.0, low_open=True, high=100.0)

    def check(self) -> None:
        super().check()
        if len(self.depth_times_s) != len(self.depth_mm) or not self.depth_mm:
            self.fail('depth_mm', f'needs one value per depth_times_s entry '
                                  f'({len(self.depth_times_s)})')
        if self.depth_times_s[0] != 0.0:
            self.fail('depth_times_s', 'must start at 0')
        if any(b <= a for a, b in zip(self.depth_times_s, self.depth_times_s[1:], strict=False)):
            self.fail('depth_times_s', 'must be strictly increasing')
        for name in ('override_cancel_span_s', 'feed_hold_span_s', 'dry_run_span_s'):
            span = getattr(self, name)
            if len(span) != 2 or span[1] < span[0]:
                self.fail(name, 'expected one [start, end) pair, its end at or after its start')
        for name in ('program_enable_spans_s', 'threading_spans_s'):
            spans = getattr(self, name)
            if len(spans) % 2 or any(b < a for a, b in zip(spans[::2], spans[1::2],
                                                           strict=True)):
                self.fail(name, 'expected [start, end) pairs, each end at or after its start')
        for name in ('tool_numbers', 'tool_specific_cutting_force_n_mm2',
                     'tool_cutting_exponent'):
            if len(getattr(self, name)) != len(self.tool_times_s):
                self.fail(name, f'needs one value per tool_times_s entry '
                                f'({len(self.tool_times_s)})')
        if self.tool_times_s[0] != 0.0 or any(
                b <= a for a, b in zip(self.tool_times_s, self.tool_times_s[1:], strict=False)):
            self.fail('tool_times_s', 'must start at 0 and be strictly increasing')
        if len(self.operator_dial_times_s) != len(self.operator_dial_pct):
            self.fail('operator_dial_pct', f'needs one value per operator_dial_times_s entry '
                                           f'({len(self.operator_dial_times_s)})')
        if any(b <= a for a, b in zip(self.operator_dial_times_s, self.operator_dial_times_s[1:],
                                      strict=False)):
            self.fail('operator_dial_times_s', 'must be strictly increasing')
        per_block = self.control_period_s * self.sample_rate_hz
        whole = self.samples_per_block
        if whole < 1 or abs(per_block - whole) > 1e-6 * per_block:
            self.fail('sample_rate_hz', f'control_period_s = {self.control_period_s!r} must span '
                                        f'a whole number of samples (got {per_block:g})')

    @property
    def samples_per_block(self) -> int:
        return round(self.control_period_s * self.sample_rate_hz)

    @property
    def programmed_feed_rate_mm_min(self) -> float:
        return self.programmed_feed_mm_rev * self.spindle_speed_rpm

    @property
    def start_spindle_speed_rpm(self) -> float:
        """The spindle speed at the start: under constant surface speed the start diameter's
        (:func:`turning_force.core.plant.lathe.spindle_rpm`)."""
        if self.css_surface_speed_m_min <= 0:
            return self.spindle_speed_rpm
        return min(1000.0 * self.css_surface_speed_m_min / (math.pi * self.css_start_diameter_mm),
                   self.css_max_spindle_rpm)

    @property
    def depth_profile(self) -> DepthProfile:
        return DepthProfile(self.depth_times_s, self.depth_mm, self.depth_interpolation)

    def inputs_array(self, t_s: FloatArray) -> FloatArray:
        """:meth:`inputs_at` for many times at once: (n, 5) program enable, threading (1 set,
        0 clear), the operator's dial [%], the spindle speed [rpm] (left NaN: the closed loop
        writes the plant's) and the tool number, NaN where not wired."""
        t = np.round(np.asarray(t_s, dtype=np.float64), 9)
        out = np.full((t.size, 5), np.nan)
        if self.tool_wired:
            out[:, 4] = np.asarray(self.tool_numbers, dtype=np.float64)[self._tool_index(t)]
        for column, spans in ((0, self.program_enable_spans_s), (1, self.threading_spans_s)):
            pairs = [(a, b) for a, b in zip(spans[::2], spans[1::2], strict=True) if b > a]
            if pairs:
                out[:, column] = np.any([(t >= a) & (t < b) for a, b in pairs], axis=0)
        if self.operator_dial_wired:
            index = np.searchsorted(np.asarray(self.operator_dial_times_s), t, side='right') - 1
            out[:, 2] = np.asarray(self.operator_dial_pct)[np.maximum(index, 0)]
        return out

    def inputs_at(self, t_s: float) -> InputValues:
        """The simulated machine's inputs at ``t_s`` (``None`` where not wired)."""
        t = round(t_s, 9)   # block ends are sums of sample periods: 2.0 may read 1.9999999999

        def switch(spans: tuple[float, ...]) -> bool | None:
            pairs = [(a, b) for a, b in zip(spans[::2], spans[1::2], strict=True) if b > a]
            return any(a <= t < b for a, b in pairs) if pairs else None

        dial = None
        if self.operator_dial_wired:
            index = max(k for k, at in enumerate(self.operator_dial_times_s)
                        if at <= t or k == 0)
            dial = self.operator_dial_pct[index]
        tool = (self.tool_numbers[int(self._tool_index(np.array([t]))[0])] if self.tool_wired
                else None)
        return InputValues(switch(self.program_enable_spans_s), switch(self.threading_spans_s),
                           dial, tool_number=tool)

    def _tool_index(self, t_s: npt.ArrayLike) -> npt.NDArray[np.intp]:
        """Which entry of tool_times_s holds at each of ``t_s``."""
        index = np.searchsorted(np.asarray(self.tool_times_s), t_s, side='right') - 1
        return np.maximum(index, 0)

    def material_at(self, t_s: FloatArray) -> FloatArray:
        """The specific cutting force [N/mm^2] the tool in use meets at each of ``t_s``."""
        if not self.tool_wired:
            return np.full(np.shape(t_s), self.specific_cutting_force_n_mm2)
        table = np.asarray(self.tool_specific_cutting_force_n_mm2)
        return table[self._tool_index(np.round(np.asarray(t_s, dtype=np.float64), 9))]


@dataclass(frozen=True)
class DepthProfile:
    """Depth of cut over time: steps (Park Fig. 6) or a linear taper between break points."""

    times_s: tuple[float, ...]
    depth_mm: tuple[float, ...]
    interpolation: str = 'step'

    def at(self, t_s: FloatArray) -> FloatArray:
        """Depth of cut [mm] at times ``t_s``."""
        times, depths = np.asarray(self.times_s), np.asarray(self.depth_mm, dtype=np.float64)
        if self.interpolation == 'linear':
            out: FloatArray = np.interp(t_s, times, depths)
            return out
        index = np.searchsorted(times, t_s, side='right') - 1
        return depths[np.clip(index, 0, depths.size - 1)]

    def change_times_s(self) -> tuple[float, ...]:
        """Times after the start at which the depth starts to change (steps or taper ends)."""
        changes = []
        for k in range(1, len(self.times_s)):
            if self.depth_mm[k] != self.depth_mm[k - 1]:
                start = self.times_s[k] if self.interpolation == 'step' else self.times_s[k - 1]
                changes.append(start)
        return tuple(sorted(set(changes)))


@dataclass(frozen=True)
class PlantBlock:
    """One control block of simulated samples: what the DAQ sees and the ground truth."""

    currents: CurrentBlock
    force_n: FloatArray
    depth_mm: FloatArray
    feed_mm_rev: FloatArray
    override_pct: float
    inputs: InputValues = NO_INPUTS       # the machine's inputs at the end of the block
    spindle_speed_rpm: float = math.nan   # the spindle's speed at the end of the block [rpm]


class Dynamometer:
    """A table dynamometer under the tool, as Park calibrated Eq. 26 with: one reading per
    block, the block's mean true force plus Gaussian noise of ``noise_n``. Its noise has a
    generator of its own, so that fitting one changes nothing else the plant draws."""

    def __init__(self, noise_n: float, seed: int) -> None:
        self.noise_n = noise_n
        self._rng = np.random.default_rng([seed, 0x44594E])

    def read_n(self, force_n: FloatArray) -> float:
        """The reading for a block whose true force samples are ``force_n`` [N]."""
        noise = float(self._rng.normal(0.0, self.noise_n)) if self.noise_n > 0 else 0.0
        return float(np.mean(force_n)) + noise
