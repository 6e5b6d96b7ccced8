"""Parameter sweeps, and the replay of many sessions, on all local cores or a Dask cluster.

:func:`sweep` runs every combination of a grid of settings (:func:`parse_grid`: one axis per
setting, ``START:STOP:N``, ``START:STOP:Nlog`` or ``v1,v2,...``), closed loop on the simulator
or open loop on a recorded session, and scores each point with the DESIGN.md metrics. Every
value is checked against its setting before anything runs; what fails at one point while it
runs is that point's ``error``, and the sweep goes on. :func:`replay_sessions` replays many
sessions with one set of changes. docs/sessions.md shows both at work.

The points go to worker processes ('forkserver': no fork of a process with threads) in chunks;
each worker loads the compiled kernel once. With ``dask=SCHEDULER_ADDRESS`` (or a
``distributed.Client``; dask is imported only then) chunks go out with ``Client.map``: the
workers need the same turning_force, and the files at the same paths. Results are the same as
on the local cores, bit for bit. ``test/bench/bench_sweep.py`` measures it.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import os
import re
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from turning_force.core.errors import ConfigError, TurningForceError, shortened
from turning_force.core.experiment import (
    OTHER_SECTIONS,
    SETTINGS_OF,
    SHARED,
    Experiment,
    check_node,
    load_experiment,
    parse_set,
)
from turning_force.core.metrics import METRIC_NAMES
from turning_force.core.yamlfile import load_yaml, yaml_error_text, yaml_text

if TYPE_CHECKING:
    from turning_force.session.reader import Session

__all__ = ['BETTER', 'DEFAULT_METRIC', 'REPLAY_COLUMNS', 'Axis', 'DaskScheduler', 'SessionReplay',
           'SweepResult',
           'parse_axis', 'parse_grid', 'replay_sessions', 'replay_totals', 'sweep']

# Which way each metric is better (core/metrics.py): errors, times, ripple and override changes
# lower; the share of the cut that could reach the reference higher.
BETTER: Mapping[str, str] = {name: 'higher' if name == 'reachable_fraction' else 'lower'
                             for name in METRIC_NAMES}
# The papers' average tracking error.
DEFAULT_METRIC = 'steady_mean_abs_error_n'
# What an open-loop point adds: how far the re-run is from the recording (replay's comparison).
REPLAY_COLUMNS = ('max_force_difference_n', 'max_request_difference_pct', 'differing_overrides',
                  'differing_reasons')
# How the metrics of several sessions add up: the means and rates as means weighted by blocks,
# the worst cases (max error, overshoot, settling time, ripple) as maxima.
TOTAL_OF: Mapping[str, str] = {
    name: 'mean' if name in ('mean_abs_error_n', 'steady_mean_abs_error_n',
                             'override_changes_per_s', 'reachable_fraction') else 'max'
    for name in METRIC_NAMES}
# A table of more rows than this would not fit in memory; no sweep needs it.
MAX_POINTS = 10_000_000
GRID_FORMS = 'expected node.param=START:STOP:N, START:STOP:Nlog or v1,v2,...'


# -- the grid -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Axis:
    """One setting swept: ``node.param``, its values in order, and how they were given."""

    name: str
    values: tuple[Any, ...]
    log: bool = False       # log-spaced (START:STOP:Nlog): plotted as such
    text: str = ''          # as given, for errors ('node.param=...')

    @property
    def where(self) -> str:
        return f'--grid {self.text or self.name!r}'

    def set_text(self, value: Any) -> str:
        """The ``--set`` assignment of one of the values (its YAML reads back to it)."""
        return f'{self.name}={yaml_text(value)}'


GridSpec = Mapping[str, 'Sequence[Any] | str'] | Sequence['str | Axis']


def parse_grid(grid: GridSpec) -> list[Axis]:
    """The axes of a grid: ``['node.param=START:STOP:N', ...]`` (the command's ``--grid``
    texts), ``{'node.param': [v1, v2] or 'START:STOP:N'}``, or :class:`Axis` objects.
    A :class:`ConfigError` names the bad axis and value (the values' specs are checked by
    :func:`sweep`, against the experiment)."""
    axes: list[Axis] = []
    if isinstance(grid, Mapping):
        for name, values in grid.items():
            if isinstance(values, str):
                axes.append(parse_axis(f'{name}={values}'))
            else:
                axes.append(_axis(str(name), list(values), False, str(name)))
    else:
        for item in grid:
            axes.append(item if isinstance(item, Axis) else parse_axis(item))
    if not axes:
        raise ConfigError('--grid: no axes; give at least one node.param=...')
    seen: dict[str, str] = {}
    for axis in axes:
        if axis.name in seen:
            raise ConfigError(f'{axis.where}: {axis.name} is swept by {seen[axis.name]!r} '
                              'already; one axis per setting')
        seen[axis.name] = axis.text or axis.name
    points = math.prod(len(a.values) for a in axes)
    if points > MAX_POINTS:
        raise ConfigError(f'--grid: {points} points; at most {MAX_POINTS} in one sweep')
    return axes


def parse_axis(text: str) -> Axis:
    """One ``--grid`` text: ``node.param=START:STOP:N``, ``...:Nlog`` or ``v1,v2,...``."""
    where = f'--grid {text!r}'
    target, sep, raw = text.partition('=')
    node, dot, param = target.strip().rpartition('.')
    if not (sep and dot and node and param and raw.strip()):
        raise ConfigError(f'{where}: {GRID_FORMS}')
    name = f'{node}.{param}'
    check_node(node, f'{where}: unknown node {node!r}')
    stripped = raw.strip()
    if ':' in stripped and stripped[0] not in '[{"\'':
        values, log = _range(stripped, name, where)
        return _axis(name, values, log, text)
    try:
        values = load_yaml(f'[{raw}]')
    except yaml.YAMLError as exc:
        raise ConfigError(f'{where}: not a list of YAML values ({GRID_FORMS}): '
                          f'{yaml_error_text(exc)}') from exc
    if not isinstance(values, list) or not values or any(v is None for v in values):
        raise ConfigError(f'{where}: an empty value; {GRID_FORMS}')
    return _axis(name, values, False, text)


def _declared(node: str, param: str) -> tuple[type, bool] | None:
    """The setting's scalar type and whether it is a list, where a node declares it."""
    kinds = [*SETTINGS_OF.values(), *OTHER_SECTIONS.values()] if node == SHARED else [
        k for k in (SETTINGS_OF.get(node), OTHER_SECTIONS.get(node)) if k is not None]
    for kind in kinds:
        declared = kind.fields().get(param)
        if declared is not None:
            default = next(f.default for f in dataclasses.fields(kind)   # type: ignore[arg-type]
                           if f.name == param)
            return declared[0], isinstance(default, tuple)
    return None   # Experiment.with_sets names it as unknown when the values are checked


def _range(raw: str, name: str, where: str) -> tuple[list[Any], bool]:
    parts = raw.split(':')
    if len(parts) != 3:
        raise ConfigError(f'{where}: expected START:STOP:N (or Nlog), got {raw!r}')
    try:
        start, stop = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(f'{where}: START and STOP must be numbers, got {parts[0].strip()!r} '
                          f'and {parts[1].strip()!r}') from None
    if not (math.isfinite(start) and math.isfinite(stop)):
        raise ConfigError(f'{where}: START and STOP must be finite')
    count = re.fullmatch(r'\s*([+-]?\d+)\s*(log)?\s*', parts[2])
    if count is None:
        raise ConfigError(f'{where}: N = {parts[2].strip()!r}: expected a whole number of '
                          'points, or Nlog for log-spaced ones')
    n, log = int(count[1]), bool(count[2])
    if n < 1:
        raise ConfigError(f'{where}: N = {n}: need at least 1 point')
    if n > MAX_POINTS:
        raise ConfigError(f'{where}: N = {n}: at most {MAX_POINTS} points')
    if log and not (start > 0 and stop > 0):
        raise ConfigError(f'{where}: a log-spaced range needs START and STOP above 0')
    declared = _declared(*name.rsplit('.', 1))
    if declared is not None and (declared[1] or declared[0] in (str, bool)):
        what = 'a list' if declared[1] else f'a {declared[0].__name__}'
        raise ConfigError(f'{where}: {name} is {what}: give its values as v1,v2,...')
    spaced = np.geomspace(start, stop, n) if log else np.linspace(start, stop, n)
    values: list[Any] = [float(v) for v in spaced]
    if declared is not None and declared[0] is int:
        bad = [v for v in values if v != round(v)]
        if bad:
            raise ConfigError(f'{where}: {name} takes whole numbers; the range gives '
                              f'{", ".join(f"{v:g}" for v in bad[:3])}')
        values = [round(v) for v in values]
    return values, log


def _axis(name: str, values: list[Any], log: bool, text: str) -> Axis:
    where = f'--grid {text or name!r}'
    if '.' not in name:
        raise ConfigError(f'{where}: {GRID_FORMS}')
    node, param = name.rsplit('.', 1)
    check_node(node, f'{where}: unknown node {node!r}')
    if not values:
        raise ConfigError(f'{where}: no values')
    declared = _declared(node, param)
    out: list[Any] = []
    for value in values:
        if isinstance(value, list):
            value = tuple(value)
        # An integer where a float is declared is that float (as Settings reads it), so that
        # the table says what ran.
        if (declared is not None and declared[0] is float and not declared[1]
                and isinstance(value, int) and not isinstance(value, bool)):
            value = float(value)
        if value in out:
            raise ConfigError(f'{where}: {yaml_text(value)} is given twice')
        out.append(value)
    return Axis(name, tuple(out), log, text)


# -- the points -----------------------------------------------------------------------------

# Where a point's settings can be built by replacing fields of one section (node -> the
# Experiment's attribute): what Experiment.with_sets gives, without parsing YAML and
# validating every section again (with_sets costs about 1 ms a point, a quarter of Fig. 8's
# run on the kernel; the replacement a quarter of that). Not for the settings tied across
# sections (build_experiment checks those together) nor '/**'.
_FAST_SECTIONS: Mapping[str, str] = {
    'experiment': 'run', 'lathe_sim': 'plant', 'force_estimator': 'estimator',
    'force_controller': 'controller', 'pmc_bridge': 'bridge'}
_TIED = frozenset(('control_period_s', 'reference_force_n', 'overload_force_n',
                   'max_feed_force_n', 'override_table', 'armed', 'arm_bridge'))


@dataclass(frozen=True)
class _Job:
    """What every worker needs, sent once: the settings, and per axis each value's --set."""

    base: Experiment
    sets: tuple[str, ...]                       # applied before the grid (--set)
    axes: tuple[tuple[str, ...], ...]           # per axis, its values' --set texts
    bag: str | None = None                      # open loop on this session
    partial: bool = False
    bag_stamp: int = 0                          # its metadata's time: a rewritten bag is new
    # base.with_sets(sets), and per axis (node, param, values) where every axis can be set by
    # replacing a field (see _FAST_SECTIONS; the sweep checks that both ways agree).
    start: Experiment | None = None
    fast: tuple[tuple[str, str, tuple[Any, ...]], ...] = ()

    def index(self, k: int) -> tuple[int, ...]:
        return tuple(int(i) for i in np.unravel_index(k, tuple(len(a) for a in self.axes)))

    def point_sets(self, k: int) -> tuple[str, ...]:
        return (*self.sets, *(texts[i] for texts, i in zip(self.axes, self.index(k),
                                                             strict=True)))

    def experiment(self, k: int, built: dict[Any, Any]) -> Experiment:
        """Point ``k``'s settings: ``base.with_sets(point_sets(k))``. ``built``: sections
        built already (the points of a chunk share most of them)."""
        if self.start is None or not self.fast:
            return self.base.with_sets(self.point_sets(k))
        changes: dict[str, dict[str, Any]] = {}
        for (node, param, values), i in zip(self.fast, self.index(k), strict=True):
            changes.setdefault(node, {})[param] = values[i]
        replaced: dict[str, Any] = {}
        sections = dict(self.start.sections)
        for node, params in changes.items():
            attr = _FAST_SECTIONS[node]
            key = (node, tuple(params.items()))
            if key not in built:
                if len(built) > 4096:
                    built.clear()
                built[key] = getattr(self.start, attr).replace(**params)
            replaced[attr] = built[key]
            # As with_sets records them: what the YAML read (lists, not tuples).
            sections[node] = {**sections.get(node, {}), **{
                p: list(v) if isinstance(v, tuple) else v for p, v in params.items()}}
        return dataclasses.replace(self.start, sections=sections, **replaced)


# The session an open-loop sweep replays, read once per worker process (a Dask worker keeps
# it from one sweep to the next, unless the bag was written again).
_SESSIONS: dict[tuple[str, bool, int], Session] = {}


def _bag_stamp(bag: str) -> int:
    try:
        return (Path(bag) / 'metadata.yaml').stat().st_mtime_ns
    except OSError:   # read_session says what is wrong with the bag
        return 0


def _session(bag: str, partial: bool, stamp: int) -> Session:
    from turning_force.session.reader import read_session

    key = (bag, partial, stamp)
    if key not in _SESSIONS:
        _SESSIONS.clear()   # one at a time: an hour-long session is large
        _SESSIONS[key] = read_session(bag, partial)
    return _SESSIONS[key]


def _load_kernel() -> None:
    """Load the compiled kernel in this process (once: a worker's first chunk)."""
    from turning_force.core import kernel

    kernel.load()


def _error_text(exc: BaseException) -> str:
    text = str(exc) if isinstance(exc, TurningForceError) else f'{type(exc).__name__}: {exc}'
    return ' '.join(text.split())


def _run_chunk(job: _Job, start: int, stop: int) -> list[dict[str, Any]]:
    """Points ``start`` .. ``stop - 1`` of the grid: per point its metrics and any error (as
    text: one point's failure is not the sweep's)."""
    _load_kernel()
    built: dict[Any, Any] = {}
    out = []
    for k in range(start, stop):
        try:
            out.append(_simulate_point(job.experiment(k, built)) if job.bag is None else
                       _replay_point(job, job.point_sets(k)))
        except Exception as exc:   # kept in the table: the point's error, not the sweep's
            out.append({'error': _error_text(exc)})
    return out


def _simulate_point(experiment: Experiment) -> dict[str, Any]:
    from turning_force.core.kernel.simulate import simulate

    result = simulate(experiment)
    return {name: result.metrics.get(name, math.nan) for name in METRIC_NAMES}


def _replay_point(job: _Job, sets: Sequence[str]) -> dict[str, Any]:
    from turning_force.session.replay import replay

    assert job.bag is not None
    session = dataclasses.replace(_session(job.bag, job.partial, job.bag_stamp),
                                  experiment=job.base)
    result = replay(session, sets)
    out: dict[str, Any] = {name: result.rerun.get(name, math.nan) for name in METRIC_NAMES}
    for name in REPLAY_COLUMNS:
        out[name] = getattr(result, name)
    return out


# -- running them: this process, local processes, or Dask --------------------------------

def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not Linux
        return os.cpu_count() or 1


def _progress_bar(total: int, enabled: bool, unit: str) -> Any:
    from tqdm import tqdm

    # Shown once a run has taken a second: short sweeps print nothing.
    return tqdm(total=total, unit=unit, disable=not enabled, delay=1.0, smoothing=0.1,
                dynamic_ncols=True, leave=False)


def _pool(jobs: int) -> Any:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # forkserver: each worker is a fork of a server process that runs no threads, never of
    # this one (rclpy's threads, the kernel's loader). The server imports the kernel once
    # (numba's import and the cached machine code, about a second), so that every worker of
    # every sweep starts with it; the initializer only finishes the load.
    context = multiprocessing.get_context('forkserver')
    context.set_forkserver_preload(['__main__', 'turning_force.core.kernel.loops'])
    return ProcessPoolExecutor(jobs, mp_context=context, initializer=_load_kernel)


def _map(func: Callable[..., Any], shared: Any, calls: Sequence[tuple[Any, ...]], jobs: int,
         dask: Any, done: Callable[[int, Any], None]) -> str:
    """``func(shared, *call)`` for every call, on ``jobs`` processes (1: this one) or, where
    ``dask`` is given, on its cluster (:func:`_map_dask`); ``done(i, result)`` as each
    finishes, in any order. Returns where they ran ('this process', '2 processes',
    'dask tcp://...')."""
    if dask is not None:
        return f'dask {_map_dask(dask, func, calls, shared, done)}'
    if jobs <= 1:
        _load_kernel()
        for i, call in enumerate(calls):
            done(i, func(shared, *call))
        return 'this process'
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    with _pool(jobs) as pool:
        futures = {pool.submit(func, shared, *call): i for i, call in enumerate(calls)}
        try:
            for future in as_completed(futures):
                done(futures[future], future.result())
        except BrokenProcessPool as exc:
            raise TurningForceError(f'a worker process died: {exc}') from exc
        finally:
            for future in futures:
                future.cancel()
    return f'{jobs} processes'


LOCAL_HOSTS = ('127.0.0.1', 'localhost', '::1', '[::1]')


@dataclass(frozen=True)
class DaskScheduler:
    """A Dask scheduler to send work to: its address, and for ``tls://`` the certificates that
    reach it (distributed's :class:`distributed.security.Security` is built from them).

    A scheduler on another host runs whatever it is sent, and the work carries the sessions and
    settings: over plain ``tcp://`` anyone on the network can read and alter both. Such an
    address is refused unless ``insecure`` says the network is trusted; ``tls://`` needs the
    CA, certificate and key files."""

    address: str
    tls_ca_file: str | None = None
    tls_cert_file: str | None = None
    tls_key_file: str | None = None
    insecure: bool = False

    def __post_init__(self) -> None:
        scheme, sep, rest = self.address.partition('://')
        host = rest.rsplit(':', 1)[0] if sep else self.address.rsplit(':', 1)[0]
        given = [f for f in (self.tls_ca_file, self.tls_cert_file, self.tls_key_file) if f]
        if scheme == 'tls' and sep:
            if len(given) != 3:
                raise TurningForceError(f'--dask {shortened(self.address)}: tls:// needs '
                                        '--tls-ca, --tls-cert and --tls-key')
            for name in given:
                if not Path(name).is_file():
                    raise TurningForceError(f'--dask {shortened(self.address)}: {name}: no such '
                                            'file')
            return
        if given:
            raise TurningForceError(f'--dask {shortened(self.address)}: --tls-ca, --tls-cert '
                                    'and --tls-key are for a tls:// address')
        if host not in LOCAL_HOSTS and not (scheme == 'inproc' and sep) and not self.insecure:
            raise TurningForceError(
                f'--dask {shortened(self.address)}: a scheduler on another host without TLS '
                '(anyone on the network could read the sessions and run code on the workers): '
                'give a tls:// address with --tls-ca, --tls-cert and --tls-key, or --insecure '
                'on a network you trust')

    def security(self) -> Any:
        """distributed's Security for this address (None: plain)."""
        if self.tls_ca_file is None:
            return None
        from distributed.security import Security

        return Security(tls_ca_file=self.tls_ca_file,   # type: ignore[no-untyped-call]
                        tls_client_cert=self.tls_cert_file, tls_client_key=self.tls_key_file,
                        require_encryption=True)


def _map_dask(dask: Any, func: Callable[..., Any], calls: Sequence[tuple[Any, ...]],
              shared: Any, done: Callable[[int, Any], None]) -> str:
    """The same on a Dask cluster: ``func(shared, *call)``, ``shared`` sent to every worker
    once. ``dask``: a :class:`DaskScheduler`, an address (checked as one), or a
    ``distributed.Client``. Returns the scheduler's address."""
    try:
        import distributed
    except ImportError:
        raise TurningForceError('--dask: dask.distributed is not installed; pip install '
                                "'turning_force[dask]'") from None
    own = not isinstance(dask, distributed.Client)
    scheduler = (dask if isinstance(dask, DaskScheduler) else DaskScheduler(str(dask))) \
        if own else None
    address = scheduler.address if scheduler is not None else str(dask.scheduler.address)
    connect: Any = distributed.Client
    try:
        client = (connect(address, timeout='10s', security=scheduler.security())
                  if scheduler is not None else dask)
    except (OSError, TimeoutError, ValueError) as exc:
        raise TurningForceError(f'--dask {address}: cannot connect: {_error_text(exc)}') \
            from exc
    try:
        sent = client.scatter(shared, broadcast=True)
        futures = [client.submit(func, sent, *call, pure=False) for call in calls]
        index = {future.key: i for i, future in enumerate(futures)}
        for future in distributed.as_completed(futures):   # type: ignore[no-untyped-call]
            try:
                result = future.result()
            except Exception as exc:   # the task itself failed there: an install problem
                raise TurningForceError(
                    f'--dask {address}: a task failed on the cluster ({_error_text(exc)}); do '
                    'its workers have turning_force installed?') from exc
            done(index[future.key], result)
    finally:
        if own:
            client.close()
    return address


@dataclass
class SweepResult:
    """Every point of a sweep: ``table`` has one row per point, in grid order (the last axis
    fastest): the axes' values, every metric (NaN where a point has none: an error, or no
    cut), replay's comparison columns (open loop) and the error ('' if none)."""

    axes: tuple[Axis, ...]
    table: list[dict[str, Any]]
    metric: str = DEFAULT_METRIC
    experiment: str = ''
    sets: tuple[str, ...] = ()
    replayed: str = ''          # the session, for an open-loop sweep
    ran_on: str = ''            # 'this process', '2 processes', 'dask tcp://...'
    wall_s: float = 0.0
    columns: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        if not self.columns:
            extra = REPLAY_COLUMNS if self.replayed else ()
            self.columns = (*(a.name for a in self.axes), *METRIC_NAMES, *extra, 'error')

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(a.values) for a in self.axes)

    @property
    def errors(self) -> list[dict[str, Any]]:
        return [row for row in self.table if row['error']]

    def _metric(self, metric: str | None) -> str:
        return _check_metric(metric or self.metric)

    def ranked(self, metric: str | None = None) -> list[int]:
        """Indices of the points with a number for ``metric``, best first (ties: grid
        order)."""
        metric = self._metric(metric)
        sign = 1.0 if BETTER[metric] == 'lower' else -1.0
        scored = [(sign * float(row[metric]), k) for k, row in enumerate(self.table)
                  if not row['error'] and math.isfinite(float(row[metric]))]
        return [k for _, k in sorted(scored)]

    def best(self, metric: str | None = None, k: int = 1) -> list[dict[str, Any]]:
        """The ``k`` best rows by ``metric`` (default: the sweep's), best first."""
        return [self.table[i] for i in self.ranked(metric)[:k]]

    def point_sets(self, row: Mapping[str, Any]) -> list[str]:
        """The ``--set`` assignments that run a row's point again (the sweep's own first)."""
        return [*self.sets, *(a.set_text(row[a.name]) for a in self.axes)]

    def _cell(self, value: Any) -> Any:
        if isinstance(value, bool | tuple | list):
            return yaml_text(value)
        if isinstance(value, float):
            return repr(value)
        return value

    def to_csv(self, path: str | Path) -> Path:
        """The table as CSV: floats written to round-trip, lists and booleans as YAML."""
        path = Path(path)
        with path.open('w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow(self.columns)
            for row in self.table:
                writer.writerow([self._cell(row[c]) for c in self.columns])
        return path

    def to_parquet(self, path: str | Path) -> Path:
        """The table as Parquet (pyarrow: ``pip install 'turning_force[parquet]'``)."""
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise TurningForceError(f'{path}: writing Parquet needs pyarrow; pip install '
                                    "'turning_force[parquet]', or write .csv") from None
        columns = {c: [list(v) if isinstance(v, tuple) else v for v in
                       (row[c] for row in self.table)] for c in self.columns}
        pq.write_table(pa.table(columns), str(path))
        return Path(path)

    def write(self, path: str | Path) -> Path:
        """The table as ``.csv`` or ``.parquet``, by the name's suffix."""
        suffix = Path(path).suffix.lower()
        if suffix == '.csv':
            return self.to_csv(path)
        if suffix == '.parquet':
            return self.to_parquet(path)
        raise TurningForceError(f'--out {path}: write .csv or .parquet')

    def figure(self, path: str | Path, metric: str | None = None) -> Path:
        """A heat map of ``metric`` over the first two axes, the best point marked; a line
        for a one-axis sweep; with more axes, the slice through the best point."""
        return _write_figure(self, Path(path), self._metric(metric))


def _write_figure(result: SweepResult, path: Path, metric: str) -> Path:
    import matplotlib

    matplotlib.use('Agg')   # files only; no display is needed or wanted
    import matplotlib.pyplot as plt

    shape = result.shape
    values = np.array([math.nan if row['error'] else float(row[metric])
                       for row in result.table]).reshape(shape)
    ranked = result.ranked(metric)
    best = tuple(int(i) for i in np.unravel_index(ranked[0], shape)) if ranked else (0,) * len(
        shape)
    better = BETTER[metric]
    title = f'{result.experiment}: {metric} ({better} is better)'
    if result.replayed:
        title += f'\nopen loop on {Path(result.replayed).name}'
    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    try:
        first = result.axes[0]
        numeric0 = all(isinstance(v, int | float) and not isinstance(v, bool)
                       for v in first.values)
        if len(shape) == 1:
            x = np.array(first.values, dtype=float) if numeric0 else np.arange(shape[0])
            ax.plot(x, values, marker='o', ms=3, lw=1.2)
            if first.log:
                ax.set_xscale('log')
            if not numeric0:
                _ticks(ax.set_xticks, ax.set_xticklabels, first)
            if ranked:
                ax.plot([x[best[0]]], [values[best[0]]], marker='*', ms=16, color='tab:red',
                        ls='none', label=f'best: {yaml_text(first.values[best[0]])}')
                ax.legend()
            ax.set_xlabel(first.name)
            ax.set_ylabel(metric)
            ax.grid(True, alpha=0.3)
        else:
            second = result.axes[1]
            plane = values[(slice(None), slice(None), *best[2:])]   # type: ignore[arg-type]
            # Errors and points without a number in grey.
            cmap = plt.get_cmap('viridis' if better == 'higher' else 'viridis_r').with_extremes(
                bad='0.85')
            image = ax.imshow(np.ma.masked_invalid(plane.T), origin='lower', aspect='auto',
                              cmap=cmap, interpolation='nearest')
            fig.colorbar(image, ax=ax, label=f'{metric} ({better} is better)')
            if plane.size <= 64:   # few cells: their numbers, too
                middle = np.nanmean(plane) if np.isfinite(plane).any() else 0.0
                for (i, j), value in np.ndenumerate(plane):
                    if math.isfinite(value):
                        # Below the middle of the cell, where the best's star is.
                        ax.text(i, j - 0.3, f'{value:.3g}', ha='center', va='center',
                                fontsize='small',
                                color='white' if (value > middle) == (better == 'lower')
                                else 'black')
            _ticks(ax.set_xticks, ax.set_xticklabels, first)
            _ticks(ax.set_yticks, ax.set_yticklabels, second)
            ax.set_xlabel(first.name + (' (log-spaced)' if first.log else ''))
            ax.set_ylabel(second.name + (' (log-spaced)' if second.log else ''))
            if ranked:
                label = (f'best: {yaml_text(first.values[best[0]])}, '
                         f'{yaml_text(second.values[best[1]])}: {plane[best[0], best[1]]:.4g}')
                ax.plot([best[0]], [best[1]], marker='*', ms=18, color='tab:red',
                        markeredgecolor='white', ls='none', label=label)
                ax.legend(loc='upper right', fontsize='small')
            if len(shape) > 2:
                fixed = ', '.join(f'{a.name}={yaml_text(a.values[i])}'
                                  for a, i in zip(result.axes[2:], best[2:], strict=True))
                title += f'\nthe slice through the best point: {fixed}'
        ax.set_title(title, fontsize='medium')
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path


def _check_metric(metric: str) -> str:
    if metric not in BETTER:
        raise ConfigError(f'--metric {metric!r}: not a metric; known: {", ".join(METRIC_NAMES)}')
    return metric


def _ticks(set_ticks: Callable[..., Any], set_labels: Callable[..., Any], axis: Axis) -> None:
    """At most about a dozen labelled ticks, at the points' positions."""
    n = len(axis.values)
    where = list(range(0, n, max(1, math.ceil(n / 12))))
    set_ticks(where)
    set_labels([f'{v:.4g}' if isinstance(v, float) else yaml_text(v)
                for v in (axis.values[i] for i in where)], fontsize='small')


def sweep(experiment: Experiment | str | Path | None, grid: GridSpec, *,
          replay: str | Path | Session | None = None, sets: Sequence[str] = (),
          metric: str = DEFAULT_METRIC, jobs: int | None = None, dask: Any = None,
          progress: bool = True, partial: bool = False,
          chunk_points: int | None = None) -> SweepResult:
    """Run every point of ``grid`` (see :func:`parse_grid`) and score it.

    ``experiment``: the settings (an :class:`Experiment` or its file). ``replay``: a session
    (folder, or a :class:`Session` read already): open loop on its recorded currents, from
    its recorded settings where ``experiment`` is None. ``sets``: ``node.param=value``
    changes applied before the grid's. ``metric``: what :meth:`SweepResult.best` ranks by
    (:data:`BETTER` says which way). ``jobs``: local processes (default: every core; 1: this
    process). ``dask``: a scheduler's address or a ``distributed.Client``, instead of local
    processes. ``progress``: a progress bar on stderr once the sweep has run a second.
    ``partial``: read a session that misses messages. ``chunk_points``: points per task
    (default: up to 200, at least eight tasks per local process).

    Grid errors, and values outside a setting's range, raise :class:`ConfigError` before
    anything runs.
    """
    start_s = time.perf_counter()
    axes = parse_grid(grid)
    _check_metric(metric)
    bag: str | None = None
    shown, stamp = '', 0
    if replay is not None:
        from turning_force.session.reader import Session, read_session

        session = replay if isinstance(replay, Session) else read_session(replay, partial)
        shown = str(session.path)
        bag = str(Path(shown).resolve())   # the workers' working folder may be another
        stamp = _bag_stamp(bag)
        _SESSIONS.clear()
        _SESSIONS[(bag, partial, stamp)] = session   # this process's points use it as read
        if experiment is None:
            if session.experiment is None:
                raise TurningForceError(f'{bag}: no recorded parameters to replay with; give '
                                        'an experiment')
            experiment = session.experiment
    if experiment is None:
        raise TurningForceError('sweep: give an experiment, or a session to replay')
    base = experiment if isinstance(experiment, Experiment) else load_experiment(experiment)
    start = base.with_sets(sets)   # a bad --set is named as such, before the grid
    fast: list[tuple[str, str, tuple[Any, ...]]] = []
    for axis in axes:
        node, param = axis.name.rsplit('.', 1)
        attr = _FAST_SECTIONS.get(node) if param not in _TIED else None
        for value in axis.values:
            text = axis.set_text(value)
            if parse_set(text)[2] != (list(value) if isinstance(value, tuple) else value):
                raise ConfigError(f'{axis.where}: {value!r} does not read back from YAML')
            try:
                with_value = base.with_sets([*sets, text])
            except ConfigError as exc:
                raise ConfigError(f'{axis.where}: {exc}') from exc
            set_to = getattr(getattr(with_value, attr), param, None) if attr else None
            if not (attr and type(set_to) is type(value) and set_to == value):
                attr = None
        if attr:
            fast.append((node, param, axis.values))
    job = _Job(base, tuple(sets), tuple(tuple(a.set_text(v) for v in a.values) for a in axes),
               bag, partial, stamp, start, tuple(fast) if len(fast) == len(axes) else ())
    n = math.prod(len(a.values) for a in axes)
    workers = min(jobs or _cores(), n) if dask is None else 0
    # Chunks of up to 200 points (about a second of Fig. 8), eight or more per local worker
    # (the load evens out, the progress bar moves); on Dask, for a cluster of any size.
    share = n / (workers * 8) if workers else n / 256
    chunk = chunk_points or max(1, min(200, math.ceil(share)))
    chunks = [(a, min(a + chunk, n)) for a in range(0, n, chunk)]
    points: list[dict[str, Any] | None] = [None] * n
    with _progress_bar(n, progress, 'pt') as bar:

        def done(i: int, rows: list[dict[str, Any]]) -> None:
            a, b = chunks[i]
            points[a:b] = rows
            bar.update(b - a)

        ran_on = _map(_run_chunk, job, chunks, workers, dask, done)
    extra = REPLAY_COLUMNS if bag else ()
    table = []
    for k, (values, point) in enumerate(zip(itertools.product(*(a.values for a in axes)),
                                            points, strict=True)):
        assert point is not None, k
        row: dict[str, Any] = dict(zip((a.name for a in axes), values, strict=True))
        for name in (*METRIC_NAMES, *extra):
            row[name] = point.get(name, math.nan)
        row['error'] = point.get('error', '')
        table.append(row)
    return SweepResult(tuple(axes), table, metric, base.run.name, tuple(sets),
                       shown if bag else '', ran_on, time.perf_counter() - start_s)


# -- many sessions, one set of changes ------------------------------------------------------

@dataclass(frozen=True)
class SessionReplay:
    """One session replayed: as ``turning-force replay BAG --json`` prints it, with the
    warning of a partial session and the error of one that could not be replayed."""

    session: str
    blocks: int = 0
    metrics: dict[str, float] = field(default_factory=dict)
    recorded_metrics: dict[str, float] = field(default_factory=dict)
    comparison: dict[str, float] = field(default_factory=dict)
    warning: str = ''
    error: str = ''
    state: dict[str, Any] = field(default_factory=dict)   # Wholeness.to_json()

    def to_json(self, sets: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {'session': self.session, 'sets': list(sets),
                               'metrics': self.metrics, 'recorded_metrics': self.recorded_metrics,
                               'comparison': self.comparison}
        if self.state:
            out['session_state'] = self.state
        if self.warning:
            out['warning'] = self.warning
        if self.error:
            out['error'] = self.error
        return out


@dataclass(frozen=True)
class _ReplayJob:
    sets: tuple[str, ...]
    experiment: Experiment | None     # instead of the recorded settings
    params: tuple[str, ...]           # parameters files laid over them
    partial: bool


def _replay_bag(job: _ReplayJob, bag: str, shown: str) -> SessionReplay:
    """One session through :func:`turning_force.session.replay.replay`; an error is kept as
    the session's, not raised (the other sessions go on). ``shown``: the path as given."""
    from turning_force.session.reader import read_session
    from turning_force.session.replay import lay_settings, replay

    _load_kernel()
    try:
        session = read_session(bag, job.partial)
        lay_settings(session, job.experiment, job.params)
        result = replay(session, job.sets)
    except Exception as exc:   # this session's error, reported with it
        return SessionReplay(shown, error=_error_text(exc).replace(bag, shown))
    comparison = result.comparison(len(session.blocks))
    state = session.wholeness.to_json() if session.wholeness is not None else {}
    return SessionReplay(shown, len(session.blocks), dict(result.rerun),
                         dict(result.recorded), comparison, session.warning.replace(bag, shown),
                         state=state)


def replay_sessions(bags: Iterable[str | Path], sets: Sequence[str] = (), *,
                    experiment: Experiment | None = None, params: Sequence[str | Path] = (),
                    partial: bool = False, jobs: int | None = None, dask: Any = None,
                    progress: bool = False) -> list[SessionReplay]:
    """Replay every session with the same ``sets`` (as ``turning-force replay``), one task
    per session, on ``jobs`` local processes (default: one per core, at most one per
    session) or on a Dask cluster (``dask``). In the order given; a session that cannot be
    read or replayed has its ``error`` instead of numbers."""
    paths = [str(b) for b in bags]
    for text in sets:
        parse_set(text)   # a malformed --set is the command's error, not every session's
    # Absolute paths for the workers (a Dask worker's working folder is its own); the
    # sessions named as given.
    job = _ReplayJob(tuple(sets), experiment, tuple(str(Path(p).resolve()) for p in params),
                     partial)
    calls = [(str(Path(p).resolve()), p) for p in paths]
    out: list[SessionReplay | None] = [None] * len(paths)
    with _progress_bar(len(paths), progress, 'session') as bar:

        def done(i: int, result: SessionReplay) -> None:
            out[i] = result
            bar.update(1)

        _map(_replay_bag, job, calls, min(jobs or _cores(), len(paths)), dask, done)
    return [r for r in out if r is not None]


def replay_totals(results: Sequence[SessionReplay]) -> dict[str, Any]:
    """The sessions together: blocks and differing overrides and reasons added up, the
    largest differences, and each metric over the sessions that have it: a mean weighted by
    blocks, or the worst (:data:`TOTAL_OF`)."""
    ok = [r for r in results if not r.error]

    def total(key: str) -> dict[str, float]:
        out = {}
        for name in METRIC_NAMES:
            have = [(getattr(r, key)[name], r.blocks) for r in ok if name in getattr(r, key)]
            if not have:
                continue
            if TOTAL_OF[name] == 'max':
                out[name] = max(v for v, _ in have)
            else:
                out[name] = sum(v * b for v, b in have) / sum(b for _, b in have)
        return out

    def largest(name: str) -> float:
        found = [r.comparison[name] for r in ok if math.isfinite(r.comparison[name])]
        return max(found) if found else math.nan

    return {'sessions': len(results), 'failed': len(results) - len(ok),
            'blocks': sum(r.blocks for r in ok),
            'metrics': total('metrics'),
            'recorded_metrics': total('recorded_metrics'),
            'comparison': {
                'max_force_difference_n': largest('max_force_difference_n'),
                'max_request_difference_pct': largest('max_request_difference_pct'),
                'differing_overrides': sum(int(r.comparison['differing_overrides']) for r in ok),
                'differing_reasons': sum(int(r.comparison['differing_reasons']) for r in ok),
                'blocks': sum(r.blocks for r in ok)}}
