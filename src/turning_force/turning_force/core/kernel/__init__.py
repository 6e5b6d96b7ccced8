"""The compiled kernel: plant, estimator, controllers, gate and quantiser as numba functions
(:mod:`.jit`), and the loader that puts their machine code in the user's cache.

The plant (:class:`turning_force.core.plant.LathePlant`), the estimator
(:class:`turning_force.core.estimation.ForceEstimator`) and the control laws
(:class:`turning_force.core.control.Controller`) are written once, here, and run compiled on
every path: the nodes one block at a time, the core loop (:func:`.jit.run_core`), replay
(:func:`.jit.replay_blocks`) and sweeps many blocks at once. The same functions run as plain
Python under numba's own switch (``NUMBA_DISABLE_JIT=1``), for debugging and coverage.

The PMC gate is the one piece still written twice: the bridge's
(:class:`turning_force.core.pmc.OverrideGate`, with the shop-floor behaviours) and the kernel's,
which the core loop runs where no shop-floor behaviour is on. Where to use it is one rule,
:func:`why_python`: a setting the kernel's gate does not know sends the core loop to the
Python gate with the reason, never to different numbers. ``TURNING_FORCE_KERNEL=off`` does the
same for every core loop; ``TURNING_FORCE_KERNEL=on`` asks for the kernel's loop wherever it
runs the settings, however short the run (:func:`forced`).

:func:`load` imports (and, with a cold cache, compiles: ``cache=True`` keeps the machine code in
:func:`cache_dir`) the kernel.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib.util
import os
import sys
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import Any

from turning_force.core.settings import Settings

__all__ = ['ENV', 'KNOWN', 'LAWS', 'NEUTRAL', 'SOURCES', 'cache_dir', 'cache_is_warm', 'forced',
           'load', 'loaded', 'why_python']

ENV = 'TURNING_FORCE_KERNEL'

# Every field of each section the kernel runs (the arrays are filled from these, or they do
# not change the numbers: where the bridge's PMC bits go, the parameters' description).
KNOWN: Mapping[str, frozenset[str]] = {
    'force_estimator': frozenset((
        'friction_min_feed_mm_min', 'friction_max_feed_mm_min', 'friction_at_min_feed_a',
        'friction_at_max_feed_a', 'current_offset_a', 'current_per_force_a_n', 'force_filter',
        'lowpass_cutoff_hz', 'lowpass_order', 'derivative_time_constant_s',
        'kalman_force_noise_n', 'kalman_accel_noise_n_s2', 'current_range_a', 'rezero_below_n',
        'rezero_after_s', 'rezero_time_constant_s', 'rezero_max_change', 'max_stamp_jump_s')),
    'force_controller': frozenset((
        'controller', 'reference_force_n', 'control_period_s', 'spindle_speed_rpm',
        'programmed_feed_mm_rev', 'override_table', 'max_feed_force_n', 'quantiser',
        'unreachable_after_s', 'initial_override_pct', 'model_servo_time_constant_s',
        'model_servo_model', 'model_servo_natural_freq_rad_s', 'model_servo_damping',
        'model_dead_time_s', 'model_cutting_time_constant_s', 'smc_lambda_per_s', 'smc_eta',
        'smc_epsilon_n', 'smc_ksd_min_n_mm', 'smc_ksd_max_n_mm', 'smc_surface',
        'smc_damping_far', 'smc_damping_near', 'smc_damping_error_n', 'smc_predictor',
        'smc_gain_time_constant_s', 'smc_resonance_hz', 'smc_unmodeled_delay_s',
        'adaptive_loop_gain_per_s', 'adaptive_estimate_time_constant_s', 'asmc_pole',
        'asmc_s_t', 'asmc_f_min', 'asmc_p0', 'asmc_theta0', 'asmc_b_min', 'asmc_freeze_limit',
        'pp_natural_freq_rad_s', 'pp_damping', 'pp_gain0_n_per_pct', 'pp_dead_zone_n', 'pp_p0',
        'pp_reset_trace', 'pi_kp_pct_per_n', 'pi_ki_pct_per_n_s', 'staircase_levels_pct',
        'staircase_step_s')),
    'pmc_bridge': frozenset((
        'override_table', 'control_period_s', 'max_feed_force_n', 'armed', 'watchdog_period_s',
        'safe_override_pct', 'overload_force_n', 'backend', 'machine_file',
        # Shop-floor settings that do not change the override while the behaviours below
        # (NEUTRAL) are off and the simulated machine wires no inputs (lathe_sim, NEUTRAL):
        # the cut detector, the reaction's limit and delay, the dial's and threading's rules.
        'threading_stand_down', 'operator_dial', 'engage_force_n', 'exit_force_n',
        'engage_time_s', 'cut_settle_s', 'reaction_force_fraction', 'reaction_delay_s',
        'breakage_window_s', 'tool', 'teach_fraction')),
    'lathe_sim': frozenset((
        'friction_min_feed_mm_min', 'friction_max_feed_mm_min', 'friction_at_min_feed_a',
        'friction_at_max_feed_a', 'current_offset_a', 'current_per_force_a_n', 'seed',
        'control_period_s', 'override_table', 'sample_rate_hz', 'spindle_speed_rpm',
        'programmed_feed_mm_rev', 'specific_cutting_force_n_mm2', 'cutting_exponent',
        'cutting_time_constant_s', 'servo_model', 'servo_time_constant_s',
        'servo_natural_freq_rad_s', 'servo_damping', 'pmc_dead_time_s', 'depth_times_s',
        'depth_mm', 'depth_interpolation', 'current_noise_a', 'force_noise_fraction',
        'sensor_fault_start_s', 'sensor_fault_duration_s', 'pole_pairs',
        'ball_screw_pitch_mm',
        # The dynamometer reads the force beside the plant (lathe_sim's force/measured, its own
        # random numbers); the dial's script matters only where the dial is wired.
        'dynamometer', 'dynamometer_noise_n', 'operator_dial_times_s', 'operator_dial_pct',
        'feed_noise_mm_min')),
}
# The laws the kernel runs (force_controller.controller).
LAWS = frozenset(('smc', 'adaptive', 'adaptive_smc', 'adaptive_pp', 'pi', 'staircase'))

# Settings of behaviours the kernel does not run, at the values where they are off (a frozenset:
# any of those values): there the kernel's numbers are the reference's; at any other value the
# run goes to Python. (The shop-floor behaviours of the gate, core/shopfloor.py, and the
# simulated machine's inputs and encoder noise.)
NEUTRAL: Mapping[str, Mapping[str, Any]] = {
    'pmc_bridge': {
        'program_enable_required': False, 'rise_rate_pct_s': 0.0, 'min_cut_override_pct': 0.0,
        'air_cut_override_pct': 0.0,
        'overload_reaction': frozenset(('none', 'alarm', 'stop')),   # outputs; no hold
        'breakage_spike_fraction': 0.0, 'breakage_drop_fraction': 0.0, 'teach_in': False,
        'teach_file': ''},
    'lathe_sim': {
        'program_enable_spans_s': (0.0, 0.0), 'threading_spans_s': (0.0, 0.0),
        'operator_dial_wired': False},
}

_lock = threading.Lock()
_module: ModuleType | None = None
_error = ''


def forced() -> bool:
    """Whether the environment asks for the kernel wherever it covers the settings."""
    return os.environ.get(ENV, '').strip().lower() in ('1', 'on', 'yes', 'true', 'compiled')


def why_python(*settings: Settings | None, sections: tuple[str, ...] = ()) -> str:
    """Why these settings run on the Python path ('' where the kernel runs them): numba
    missing, ``TURNING_FORCE_KERNEL=off``, or a setting the kernel does not know.
    ``sections`` must each be among the settings' (e.g. the core loop needs the plant's)."""
    value = os.environ.get(ENV, '').strip().lower()
    if value in ('0', 'off', 'python', 'no', 'false'):
        return f'{ENV}={os.environ[ENV]}'
    if importlib.util.find_spec('numba') is None:
        return 'numba is not installed'
    if _error:
        return _error
    seen = set()
    for item in settings:
        if item is None:
            continue
        section = item.SECTION
        seen.add(section)
        known, neutral = KNOWN.get(section, frozenset()), NEUTRAL.get(section, {})
        for field in dataclasses.fields(item):   # type: ignore[arg-type]
            if field.name in known:
                continue
            value_now = getattr(item, field.name)
            if field.name not in neutral:
                return f'{section}.{field.name} is not in the compiled kernel'
            off = neutral[field.name]
            spans = isinstance(off, tuple) and field.name.endswith('_spans_s')
            if spans and not any(b > a for a, b in zip(value_now[::2], value_now[1::2],
                                                       strict=False)):
                continue
            allowed = off if isinstance(off, frozenset) else frozenset((off,))
            if value_now not in allowed:
                shown = ', '.join(sorted(map(repr, allowed)))
                return (f'{section}.{field.name} = {value_now!r} is not in the compiled kernel '
                        f'(only {shown})')
        if section == 'force_controller' and getattr(item, 'controller', '') not in LAWS:
            return (f'force_controller.controller = {getattr(item, "controller", "")!r} is not '
                    'in the compiled kernel')
    missing = [s for s in sections if s not in seen]
    if missing:
        return f'no {", ".join(missing)} settings'
    return ''


def loaded() -> ModuleType | None:
    """The kernel's module if it is loaded in this process, else None (never waits)."""
    return _module


def load() -> ModuleType:
    """The kernel's module, importing (or with a cold cache compiling) it now if need be.

    numba's machine code goes to :func:`cache_dir`, never into the installed package; a
    compilation (a new install or version) says so on stderr, and how long it took."""
    global _module, _error
    with _lock:
        if _module is None:
            where = cache_dir()
            warm = cache_is_warm()
            start = time.perf_counter()
            if not warm:
                print(f'turning_force: compiling the kernel into {where} (once per install and '
                      'version: 15 to 60 s)', file=sys.stderr, flush=True)
            try:
                from turning_force.core.kernel import jit
            except Exception as exc:   # a broken numba install: say so, run Python
                _error = f'the kernel did not load: {exc!r}'
                raise
            if not warm:
                print(f'turning_force: kernel compiled in {time.perf_counter() - start:.0f} s',
                      file=sys.stderr, flush=True)
                with contextlib.suppress(OSError):
                    (where / STAMP).write_text(_source_hash() + '\n')
            _module = jit
    return _module


STAMP = 'turning_force_kernel.sha256'
# Every module that holds compiled code. numba checks only the file that defines a function
# when it reads its cache, not the files of the functions it calls: the cache's folder is keyed
# on all of them at once (cache_dir), so that a change to any one never pairs with old code.
SOURCES = ('jit.py',)


def _source_hash() -> str:
    """The SHA-256 of every source of compiled code (:data:`SOURCES`) and of numba's version."""
    import importlib.metadata

    digest = hashlib.sha256(importlib.metadata.version('numba').encode())
    for name in SOURCES:
        digest.update(Path(__file__).with_name(name).read_bytes())
    return digest.hexdigest()


def cache_dir() -> Path:
    """Where numba keeps the kernel's machine code: ``$NUMBA_CACHE_DIR`` (or the user's cache
    folder, ``$XDG_CACHE_HOME`` or ``~/.cache``, under ``turning_force/numba``), in a folder
    named for the sources' hash."""
    base = os.environ.get('NUMBA_CACHE_DIR', '').strip()
    if not base:
        home = os.environ.get('XDG_CACHE_HOME', '').strip() or str(Path.home() / '.cache')
        base = str(Path(home) / 'turning_force' / 'numba')
    return Path(base) / _source_hash()[:20]


def cache_is_warm() -> bool:
    """Whether numba's on-disk cache holds the kernel for today's sources (a stamp :func:`load`
    leaves beside numba's files): then loading it is an import, not a compilation. Costs a
    hash of the sources, no numba."""
    stamp = cache_dir() / STAMP
    return stamp.is_file() and stamp.read_text().strip() == _source_hash()
