"""The ``turning-force`` command.

Each command's options are in its ``--help`` (``build_parser``); DESIGN.md and docs/ say what
each does.

Errors in the user's input (a bad file, key, value or bag) print one line naming it and exit 2.
A session missing messages is such an error; ``--partial`` reads what is there instead, and a
warning line on stderr says how much is missing. SIGINT or SIGTERM stops ``run`` at the end of
the step under way, closes the session, prints one line and exits 128 + the signal's number.
Each command imports what it needs when it runs (start-up: no scipy, no plotting, no ROS, no
numba before the first period; see turning_force.core.kernel).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import dataclasses
import datetime
import json
import math
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

from turning_force.core.errors import NoCutError, TurningForceError, short_repr
from turning_force.core.experiment import Experiment, load_experiment
from turning_force.core.metrics import METRIC_NAMES, OPTIONAL_METRICS
from turning_force.core.overlay import with_parameters_file
from turning_force.core.pmc.settings import handed_back

__all__ = ['main']


def _print_metrics(title: str, metrics: dict[str, float]) -> None:
    print(title)
    for name in (*METRIC_NAMES, *OPTIONAL_METRICS, 'realtime_factor'):
        if name in metrics:
            print(f'  {name:26s} {metrics[name]:10.3f}')
    if metrics.get('oscillation_alarms', 0.0) > 0.0:
        print(f'  WARNING: the loop oscillated: {metrics["oscillation_alarms"]:.0f} oscillation '
              'alarm(s); the controller reacted as oscillation_reaction says (see docs)')


class Interrupted(TurningForceError):
    """SIGINT or SIGTERM stopped the command; it exits 128 + the signal's number."""

    def __init__(self, message: str, signum: int) -> None:
        super().__init__(message)
        self.exit_status = 128 + signum
        self.signal_name = signal.Signals(signum).name   # what the session says stopped it


@contextlib.contextmanager
def _signals(defer: bool) -> Iterator[Callable[[], int | None]]:
    """SIGINT and SIGTERM as :class:`Interrupted`, never as a traceback.

    With ``defer``, a first signal is only noted, and the caller stops where it is safe to
    (a lock-step run between two steps, so that the recorder closes a consistent session): the
    context yields a function that returns the signal noted, if any. A second signal, or any
    signal without ``defer``, raises at once.
    """
    received: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        received.append(signum)
        if not defer or len(received) > 1:
            raise Interrupted(f'interrupted by {signal.Signals(signum).name}', signum)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield lambda: received[0] if received else None
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def _warn(session: Any) -> None:
    if session.warning:
        print(f'turning-force: warning: {session.warning}', file=sys.stderr)


def _read(bag: str, args: argparse.Namespace) -> Any:
    """The session ``bag`` as ``--partial`` allows, its warning printed."""
    from turning_force.session.reader import read_session

    session = read_session(bag, args.partial)
    _warn(session)
    return session


def _replayed(bag: str, args: argparse.Namespace) -> Any:
    """The session ``bag`` (:func:`_read`) with the settings to replay it with: ``--experiment``
    instead of the recorded ones where given, then the ``--params`` files."""
    from turning_force.session.replay import lay_settings

    session = _read(bag, args)
    lay_settings(session, load_experiment(args.experiment) if args.experiment else None,
                 args.params)
    return session


def _recorded(bag: Path, record: Callable[[Callable[[int, int], None]], Any],
              show: Callable[[int, int], None] | None) -> Any:
    """``record(progress)``, a recorded run, stopped by SIGINT or SIGTERM where it calls
    ``progress`` (between two steps or two batches of blocks, so that the session closes
    consistent, saying it ended early); ``show`` draws the progress."""
    with _signals(defer=True) as received:
        def progress(done: int, total: int) -> None:
            signum = received()
            if signum is not None:
                raise Interrupted(
                    f'interrupted by {signal.Signals(signum).name} after block {done} of '
                    f'{total}: the session {bag} is closed with what ran (ended early)', signum)
            if show is not None:
                show(done, total)

        outcome = record(progress)
        signum = received()
        if signum is not None:   # during the last steps
            raise Interrupted(f'interrupted by {signal.Signals(signum).name} after the run: '
                              f'the session {bag} is complete', signum)
    return outcome


def _load(path: str, params: Sequence[str], sets: Sequence[str]) -> Experiment:
    """The experiment file, the ``--params`` files laid over it in order, then ``--set``."""
    experiment = load_experiment(path)
    for file in params:
        experiment = with_parameters_file(experiment, file)
    return experiment.with_sets(sets)


def _check_writable(out: Path, flag: str, new: bool) -> None:
    """Refuse an output path before anything runs: its folder must exist and take a file.

    ``new``: ``out`` itself must not exist yet (a session is never overwritten). The folder is
    tried by creating and removing a temporary directory in it, which also catches read-only
    file systems and root on them.
    """
    where = f'{flag} {out}' if flag else str(out)
    parent = out.parent
    if not parent.is_dir():
        what = 'is not a folder' if parent.exists() else 'does not exist'
        raise TurningForceError(f'{where}: {parent} {what}')
    if new and (out.exists() or out.is_symlink()):
        raise TurningForceError(f'{where}: exists already; a session is never overwritten')
    try:
        Path(tempfile.mkdtemp(prefix='.turning_force_', dir=parent)).rmdir()
    except OSError as exc:
        raise TurningForceError(f'{where}: cannot write in {parent}: {exc.strerror}') from exc


def _check_bridge_files(experiment: Experiment, core: bool) -> None:
    """The files the bridge reads, refused before anything runs, as the bridge refuses them:
    the teach-in file; and for ``run --core`` the machine file the graph would load."""
    bridge = experiment.bridge
    if core and (bridge.machine_file or bridge.backend == 'modbus_tcp'):   # (pymodbus: 0.05 s)
        from turning_force.io.pmc_server import simulate_pmc

        simulate_pmc(bridge.machine_file, bridge.backend, bridge.override_table)
    if bridge.teach_file:
        from turning_force.core.pmc.shopfloor import load_teach_file

        load_teach_file(bridge.teach_file)   # as the bridge reads it at configure


def _run(args: argparse.Namespace) -> int:
    experiment = _load(args.experiment, args.params, args.set)
    _check_bridge_files(experiment, args.core)
    out: dict[str, Any] = {'experiment': experiment.run.name}
    if args.core:
        if args.out:
            from turning_force.commands.core_session import record_core

            bag = Path(args.out)
            out['session'] = str(bag)
            _check_writable(bag, '--out', new=True)
            progress: Callable[[int, int], None] | None = None
            if not args.json and sys.stderr.isatty():   # (session.run imports rclpy)
                from turning_force.commands.run import print_progress

                progress = print_progress
            result = _recorded(bag, lambda step: record_core(experiment, bag, step),
                               progress).run.result
        else:
            from turning_force.core.kernel.simulate import simulate

            with _signals(defer=False):
                result = simulate(experiment)
        metrics = out['metrics'] = result.metrics
        drifted = result.drift
        stopped = handed_back(result.trace['t_s'], result.trace['override_reason'])
    else:
        from turning_force.commands.run import print_progress, run_lockstep
        from turning_force.session.reader import read_session, recorded_metrics
        from turning_force.session.report import write_report

        stamp = datetime.datetime.now().strftime('%Y%m%d_%H%M%S')
        bag = Path(args.out or f'bags/{experiment.run.name}_{stamp}')
        if not args.out:
            try:
                bag.parent.mkdir(exist_ok=True)
            except OSError as exc:
                raise TurningForceError(f'{bag.parent}: cannot create: {exc.strerror}') from exc
        _check_writable(bag, '--out' if args.out else '', new=True)
        outcome = _recorded(bag, lambda step: run_lockstep(experiment, bag, step),
                            None if args.json else print_progress)
        with _signals(defer=False):   # the session is closed: a signal stops the figure
            session = read_session(bag)
            stopped = handed_back(session.t_s, session.signals['override_reason'])
            drifted = ''   # force_controller's WARN on /diagnostics, in the session
            try:
                metrics = recorded_metrics(session)
            except NoCutError:
                metrics = {}   # an air cut: recorded, nothing to score
            metrics['realtime_factor'] = outcome.realtime_factor
            figure = write_report(session, metrics, Path(f'{bag}.png'))
        out.update(session=str(bag), figure=str(figure), executor=outcome.executor,
                   metrics=metrics)
    if stopped:
        out['handed_back'] = stopped
    if drifted:
        out['drift'] = drifted
    if args.json:
        print(json.dumps(out))
        return 0
    print(f'{experiment.run.name}: {experiment.run.description}')
    if stopped:
        print(f'  {stopped}')
    if drifted:   # the graph's force_controller says it on /diagnostics
        print(f'  WARNING: the machine drifted from its identified model: {drifted}')
    if experiment.run.paper_figure:
        paper = experiment.run.paper_steady_mean_abs_error_n
        print(f'  reproduces {experiment.run.paper_figure}'
              + (f' (paper: {paper:g} N average tracking error)' if paper else ''))
    if 'figure' in out:
        print(f'  session: {out["session"]}\n  figure:  {out["figure"]}')
    elif 'session' in out:
        print(f'  session: {out["session"]} (`turning-force report` draws it)')
    _print_metrics('metrics' + (' (core loop)' if args.core else ' (from the session)'),
                   metrics)
    predicted = _prediction(args.params)
    if predicted is not None:
        print(f'identify predicted for {predicted["law"]} on the identified plant / this run:')
        for key, metric in (('steady_n', 'steady_mean_abs_error_n'),
                            ('mean_n', 'mean_abs_error_n'), ('ripple_n', 'ripple_p2p_n')):
            print(f'  {metric:30s} {predicted[key]:8.3f} / {metrics.get(metric, math.nan):8.3f}')
    return 0


def _prediction(params: Sequence[str]) -> dict[str, Any] | None:
    """The prediction ``identify`` wrote into a parameters file's header, if one is given."""
    for name in params:
        for line in Path(name).read_text().splitlines():
            if line.startswith(f'# {PREDICTION} '):
                found: dict[str, Any] = json.loads(line.split(' ', 2)[2])
                return found
    return None


def _parallel(args: argparse.Namespace) -> None:
    """--jobs and --dask checked before anything runs (args.dask becomes a DaskScheduler)."""
    if args.jobs is not None and args.jobs < 1:
        raise TurningForceError(f'--jobs {args.jobs}: need at least 1')
    if args.dask:
        from turning_force.commands.sweep import DaskScheduler

        args.dask = DaskScheduler(args.dask, args.tls_ca, args.tls_cert, args.tls_key,
                                  args.insecure)
    elif args.tls_ca or args.tls_cert or args.tls_key or args.insecure:
        raise TurningForceError('--tls-ca, --tls-cert, --tls-key and --insecure go with --dask')


def _replay(args: argparse.Namespace) -> int:
    _parallel(args)
    if len(args.bags) > 1 or args.dask:
        return _replay_many(args)
    bag = args.bags[0]
    if args.closed_loop:
        return _what_if(args, bag)
    if args.publish:
        from turning_force.commands.play import play

        _read(bag, args)   # refused, or its warning printed, before anything is played
        play(Path(bag), args.rate, partial=args.partial)
        return 0
    from turning_force.commands.run import print_progress
    from turning_force.session.replay import replay

    session = _replayed(bag, args)
    result = replay(session, args.set, None if args.json else print_progress)
    comparison = result.comparison(len(session.blocks))
    _print_replay(args, str(session.path), result.recorded, result.rerun, comparison,
                  _state(session))
    return 0


def _what_if(args: argparse.Namespace, bag: str) -> int:
    """``replay BAG --closed-loop``: :mod:`turning_force.session.whatif`."""
    from turning_force.session.whatif import what_if

    result = what_if(bag, args.set, args.identified_from or ())
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print(f'{bag}: closed loop on the machine identified from '
          f'{", ".join(args.identified_from or [bag])}'
          + (f', with {", ".join(args.set)}' if args.set else ', settings as recorded'))
    print('\n'.join(result.lines()))
    return 0


def _state(session: Any) -> dict[str, Any]:
    """The session's :class:`turning_force.session.reader.Wholeness` as JSON."""
    state: dict[str, Any] = session.wholeness.to_json()
    return state


def _print_replay(args: argparse.Namespace, path: str, recorded: dict[str, float],
                  rerun: dict[str, float], comparison: dict[str, Any],
                  state: dict[str, Any]) -> None:
    """One session's replay: recorded and re-run metrics side by side, and how far apart."""
    blocks = comparison['blocks']
    if args.json:
        print(json.dumps({'session': path, 'sets': list(args.set), 'metrics': rerun,
                          'recorded_metrics': recorded, 'comparison': comparison,
                          'session_state': state}))
        return
    print(f'{path} ({state["text"]}): {blocks} blocks replayed open loop'
          + (f' with {", ".join(args.set)}' if args.set else ' unchanged'))
    if recorded or rerun:
        print(f'  {"metric (estimated force)":28s} {"recorded":>10s} {"re-run":>10s}')
        for name in METRIC_NAMES:
            print(f'  {name:28s} {recorded.get(name, math.nan):10.3f} '
                  f'{rerun.get(name, math.nan):10.3f}')
    else:
        print('  no cut in this session (an air cut): no force metrics')
    print(f'  force estimates differ by at most {comparison["max_force_difference_n"]:.3g} N; '
          f'requests by {comparison["max_request_difference_pct"]:.3g} %; '
          f'{comparison["differing_overrides"]} of {blocks} overrides and '
          f'{comparison["differing_reasons"]} gate reasons differ')


def _replay_many(args: argparse.Namespace) -> int:
    """Several sessions (or one on a Dask cluster), replayed with the same changes: one row
    per session and the totals; a session that fails is its row's error, a line on stderr,
    and exit status 2 once the others are done."""
    from turning_force.commands.sweep import replay_sessions, replay_totals
    from turning_force.core.overlay import read_parameters

    if args.publish:
        raise TurningForceError('--publish plays one session; give one BAG, without --dask')
    for file in args.params:
        read_parameters(file)   # a bad file is the command's error, not every session's
    experiment = load_experiment(args.experiment) if args.experiment else None
    results = replay_sessions(args.bags, args.set, experiment=experiment, params=args.params,
                              partial=args.partial, jobs=args.jobs, dask=args.dask,
                              progress=_progress(args))
    for r in results:
        _warn(r)
    failed = [r for r in results if r.error]
    if len(results) == 1 and not failed:
        r = results[0]
        _print_replay(args, r.session, r.recorded_metrics, r.metrics, r.comparison, r.state)
    elif args.json:
        print(json.dumps({'sets': list(args.set),
                          'sessions': [r.to_json(args.set) for r in results],
                          'totals': replay_totals(results)}))
    else:
        _print_replay_table(args, results, replay_totals(results))
    for r in failed:
        print(f'turning-force: {r.error}', file=sys.stderr)
    return 2 if failed else 0


def _print_replay_table(args: argparse.Namespace, results: Sequence[Any],
                        totals: dict[str, Any]) -> None:
    steady, ripple = 'steady_mean_abs_error_n', 'ripple_p2p_n'
    print(f'{len(results)} sessions replayed open loop'
          + (f' with {", ".join(args.set)}' if args.set else ' unchanged')
          + ' (metrics on the estimated force; --json for all of them)')
    width = max(12, *(len(r.session) for r in results))
    print(f'  {"session":{width}s} {"blocks":>7s}  {"steady error [N]":>17s}  '
          f'{"ripple p2p [N]":>17s}  {"force diff":>10s}  {"overrides":>9s}')
    print(f'  {"":{width}s} {"":7s}  {"recorded":>8s} {"re-run":>8s}  {"recorded":>8s} '
          f'{"re-run":>8s}  {"max [N]":>10s}  {"differ":>9s}')

    def line(label: str, blocks: int, recorded: dict[str, float], rerun: dict[str, float],
             comparison: dict[str, Any]) -> str:
        return (f'  {label:{width}s} {blocks:7d}  {recorded.get(steady, math.nan):8.3f} '
                f'{rerun.get(steady, math.nan):8.3f}  {recorded.get(ripple, math.nan):8.3f} '
                f'{rerun.get(ripple, math.nan):8.3f}  '
                f'{comparison["max_force_difference_n"]:10.3g}  '
                f'{comparison["differing_overrides"]:9d}')

    for r in results:
        if r.error:
            print(f'  {r.session:{width}s} failed: {r.error}')
        else:
            print(line(r.session, r.blocks, r.recorded_metrics, r.metrics, r.comparison))
    done = totals['sessions'] - totals['failed']
    print(line(f'total ({done} of {totals["sessions"]})', totals['blocks'],
               totals['recorded_metrics'], totals['metrics'], totals['comparison']))
    print('  (total: steady error a mean weighted by blocks, ripple and force difference the '
          'largest, overrides added up)')


def _progress(args: argparse.Namespace) -> bool:
    """A progress bar for a terminal, not for a log or --json."""
    return not args.json and sys.stderr.isatty()


def _sweep(args: argparse.Namespace) -> int:
    from turning_force.commands.sweep import BETTER, parse_grid, sweep

    axes = parse_grid(args.grid)   # the grid's syntax before any file is read
    if args.top < 1:
        raise TurningForceError(f'--top {args.top}: need at least 1')
    _parallel(args)
    for flag, path, suffixes in (('--out', args.out, ('.csv', '.parquet')),
                                 ('--figure', args.figure, ('.png', '.svg', '.pdf'))):
        if path is None:
            continue
        if Path(path).suffix.lower() not in suffixes:
            raise TurningForceError(f'{flag} {path}: write {" or ".join(suffixes)}')
        _check_writable(Path(path), flag, new=False)
    replayed: Any = None
    if args.replay:
        replayed = _replayed(args.replay, args)
        experiment = replayed.experiment
    elif args.experiment:
        experiment = _load(args.experiment, args.params, [])
    else:
        raise TurningForceError('sweep: give EXPERIMENT, or --replay BAG')
    result = sweep(experiment, axes, replay=replayed, sets=args.set, metric=args.metric,
                   jobs=args.jobs, dask=args.dask, progress=_progress(args),
                   partial=args.partial)
    if args.out:
        result.write(args.out)
    if args.figure:
        result.figure(args.figure)
    best = result.best(k=args.top)
    failed = result.errors
    if args.json:
        print(json.dumps({
            'experiment': result.experiment, 'replayed': result.replayed or None,
            'grid': {a.name: list(a.values) for a in axes}, 'sets': list(args.set),
            'points': len(result.table), 'errors': len(failed), 'ran_on': result.ran_on,
            'wall_s': result.wall_s, 'metric': args.metric, 'better': BETTER[args.metric],
            'best': [{**row, 'sets': result.point_sets(row)} for row in best],
            'table': args.out, 'figure': args.figure}, default=list))
    else:
        _print_sweep(args, result, best)
    if not best:
        first = f'; the first: {failed[0]["error"]}' if failed else ''
        raise TurningForceError(f'sweep: no point has a number for {args.metric} '
                                f'({len(failed)} of {len(result.table)} points failed{first})')
    return 0


def _print_sweep(args: argparse.Namespace, result: Any, best: list[dict[str, Any]]) -> None:
    from turning_force.commands.sweep import BETTER

    axes = result.axes
    shape = ' x '.join(f'{len(a.values)} {a.name}' for a in axes)
    where = (f'open loop on {result.replayed}' if result.replayed
             else 'closed loop on the simulator')
    print(f'{result.experiment}: {len(result.table)} points ({shape}), {where}, on '
          f'{result.ran_on}: {result.wall_s:.1f} s')
    if args.set:
        print(f'  with {", ".join(args.set)}')
    metric = args.metric
    print(f'best by {metric} ({BETTER[metric]} is better):')
    widths = [max(len(a.name), 8) for a in axes]
    print('  rank  ' + '  '.join(f'{a.name:>{w}s}' for a, w in zip(axes, widths, strict=True))
          + f'  {metric:>{max(len(metric), 10)}s}')
    for rank, row in enumerate(best, 1):
        cells = '  '.join(f'{_cell(row[a.name]):>{w}s}' for a, w in zip(axes, widths,
                                                                         strict=True))
        print(f'  {rank:4d}  {cells}  {row[metric]:>{max(len(metric), 10)}.4f}')
    if best:
        sets = ' '.join(f"--set '{t}'" for t in result.point_sets(best[0]))
        command = (f'turning-force replay {result.replayed}' if result.replayed
                   else f'turning-force run {args.experiment}')
        params = ''.join(f' --params {p}' for p in args.params)
        print(f'  the best again: {command}{params} {sets}')
    failed = result.errors
    if failed:
        print(f'{len(failed)} of {len(result.table)} points failed (the table has each '
              f'error); the first: {failed[0]["error"]}')
    if args.out:
        print(f'table:  {args.out}')
    if args.figure:
        print(f'figure: {args.figure}')


def _cell(value: Any) -> str:
    return f'{value:.6g}' if isinstance(value, float) else str(value)


def _report(args: argparse.Namespace) -> int:
    from turning_force.session.reader import recorded_metrics
    from turning_force.session.report import write_html_report, write_report

    out = Path(args.out) if args.out else Path(str(args.bag).rstrip('/') + '.png')
    if out.suffix not in ('.png', '.html'):
        raise TurningForceError(f'--out {out}: write .png or .html')
    _check_writable(out, '--out' if args.out else '', new=False)
    session = _read(args.bag, args)
    metrics = recorded_metrics(session)
    (write_report if out.suffix == '.png' else write_html_report)(session, metrics, out)
    if args.json:
        print(json.dumps({'session': str(session.path), 'figure': str(out), 'metrics': metrics,
                          'session_state': _state(session)}))
        return 0
    _print_metrics(f'{session.path} ({_state(session)["text"]}): figure {out}', metrics)
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    if args.map:
        return _calibrate_map(args)
    from turning_force.session.calibrate import calibrate

    sessions = [_read(bag, args) for bag in args.bags]
    result = calibrate(sessions, args.settle_s)
    parameters = result.estimator_parameters()
    if args.json:
        print(json.dumps({'force_estimator': parameters, 'residual_a': result.residual_a(),
                          'points': [{'feed_mm_min': f, 'friction_current_a': i} for f, i
                                     in zip(result.feeds_mm_min, result.currents_a,
                                            strict=True)]}))
        return 0
    print('air cuts (mean feed, friction current):')
    for feed, current in zip(result.feeds_mm_min, result.currents_a, strict=True):
        print(f'  {feed:8.1f} mm/min  {current:7.4f} A')
    print(f'Park Eq. 25 fitted, largest residual {result.residual_a():.4f} A; for the '
          'experiment file:')
    print('/**/force_estimator:\n  ros__parameters:')
    for name, value in parameters.items():
        print(f'    {name}: {value:.6g}')
    return 0


def _calibrate_map(args: argparse.Namespace) -> int:
    from turning_force.session.identify import calibrate_map_sessions, format_parameters

    result = calibrate_map_sessions(args.bags, args.axis)
    parameters = result.estimator_parameters()
    recorded = result.recorded
    bias = result.regulation_bias_n(args.reference_n)
    if args.json:
        print(json.dumps({
            'force_estimator': parameters,
            'uncertainty': {'current_offset_a': result.offset_a.std,
                            'current_per_force_a_n': result.per_force_a_n.std},
            'residual_rms_a': result.residual_rms_a, 'blocks': result.blocks,
            'force_range_n': list(result.force_range_n),
            'recorded': {'current_offset_a': recorded.offset_a,
                         'current_per_force_a_n': recorded.per_force_a_n},
            'regulation_bias_n': bias}))
    else:
        low, high = result.force_range_n
        slope_change = (result.per_force_a_n.value / recorded.per_force_a_n - 1.0) * 100.0
        print(f'{", ".join(result.sessions)}: {result.blocks} blocks, dynamometer '
              f'{low:.0f}-{high:.0f} N')
        print('Park Eq. 26, i_q - I_fric = offset + slope F:')
        print(f'  offset  {result.offset_a.value:10.5f} A    +/- {result.offset_a.std:.2g}   '
              f'(recorded {recorded.offset_a:.5f})')
        print(f'  slope   {result.per_force_a_n.value:10.6f} A/N  +/- '
              f'{result.per_force_a_n.std:.2g}   (recorded {recorded.per_force_a_n:.6f}: '
              f'{slope_change:+.1f} %)')
        print(f'  residual {result.residual_rms_a:.4f} A rms '
              f'({result.residual_rms_a / result.per_force_a_n.value:.2f} N)')
        print(f'  the recorded map regulated {args.reference_n:g} N to '
              f'{args.reference_n + bias:.1f} N ({bias:+.1f} N)')
    text = format_parameters({'force_estimator': parameters}, [
        f'turning-force calibrate --map {" ".join(map(str, args.bags))}',
        'The current-to-force map (Park Eq. 26) against a dynamometer; load with',
        '  turning-force run EXPERIMENT.yaml --params THIS_FILE'])
    _emit_parameters(text, args)
    return 0


def _emit_parameters(text: str, args: argparse.Namespace) -> None:
    """A parameters file to ``--out``, or (without ``--json``) to stdout."""
    if args.out:
        Path(args.out).write_text(text)
        if not args.json:
            print(f'parameters written to {args.out}')
    elif not args.json:
        print(text, end='')


def _parse_range(text: str | None, option: str) -> tuple[float, float] | None:
    if text is None:
        return None
    low, sep, high = text.partition(':')
    try:
        values = (float(low), float(high) if sep else float(low))
    except ValueError:
        raise TurningForceError(f'{option} {text!r}: expected MIN:MAX') from None
    if not (0.0 < values[0] <= values[1] and math.isfinite(values[1])):
        raise TurningForceError(f'{option} {text!r}: need 0 < MIN <= MAX')
    return values


def _identify(args: argparse.Namespace) -> int:
    from turning_force.core.control import drift
    from turning_force.core.experiment import assignments, parse_set
    from turning_force.core.identify import IdentifySettings
    from turning_force.core.verification import (
        drifted_plants,
        entry_depths_mm,
        entry_override_pct,
        friction_beyond_reach,
        starts_in_air,
        verify,
    )
    from turning_force.session.identify import cut_depth_mm, format_parameters, identify_sessions

    depths = _job_depths(args)
    settings = IdentifySettings(cut_force_n=args.cut_force_n)
    ident, sessions = identify_sessions(args.bags, settings,
                                        [args.prior] if args.prior else None)
    cut_depth = args.cut_depth_mm or cut_depth_mm(sessions)
    if cut_depth is None:
        raise TurningForceError('--depths-mm needs --cut-depth-mm: the sessions do not say '
                                'how deep the commissioning cut was')
    job = _verification_job(args, sessions[0].experiment, depths)
    if args.tool is not None:   # the tool's own reference and limits
        job = job.with_sets(_tool_limits(args))
    found = ident.parameters(depths, cut_depth, job.controller.reference_force_n,
                             args.ksd_margin)
    controller, estimator = found['force_controller'], found['force_estimator']
    if args.job and starts_in_air(job.plant.depth_profile):   # its approach reads the friction
        estimator['rezero_start_in_air'] = True
    low, high = float(controller['smc_ksd_min_n_mm']), float(controller['smc_ksd_max_n_mm'])
    # the entry feed for the depths the job enters at (--depths-mm: its deepest)
    entry_depths = entry_depths_mm(job.plant.depth_profile) if args.job else depths[1:]
    entry = entry_override_pct(ident, job, entry_depths, cut_depth)
    if entry is not None:
        found['pmc_bridge'] = {'air_cut_override_pct': entry}
        entry_line = (f'entry feed: {entry:g} % (pmc_bridge.air_cut_override_pct; at '
                      f"{job.bridge.air_cut_override_pct:g} % the force at the job's deepest "
                      f'entry, {max(entry_depths):g} mm, would settle over the reference)')
    identified = [*assignments('force_controller', controller),
                  *assignments('force_estimator', estimator),
                  *assignments('pmc_bridge', found.get('pmc_bridge', {}))]
    # the drift monitor watches the identified model while cutting (where --job gives the
    # job, the depth its program starts at as well); the verification cuts with it, as written
    monitor = drift.identified(ident, job, depths, cut_depth,
                               job.plant.depth_profile if args.job else None)
    predictions = verify(job, ident, identified, cut_depth, plants=args.plants,
                         monitor=assignments('force_controller', monitor))
    chosen = predictions[0]
    for assignment in chosen.sets[len(identified):]:   # the chosen law's own settings
        node, key, value = parse_set(assignment)
        found[node][key] = value
    found['force_controller'].update(monitor)
    sections: Mapping[str, Mapping[str, Any]] = (
        found if chosen.name != 'defaults' else {'force_controller': {}})
    if args.json:
        # every fit with its parameters (value, std, unit), residual, samples and BIC
        print(json.dumps({**dataclasses.asdict(ident), 'cut_depth_mm': cut_depth,
                          'force_controller': controller, 'force_estimator': estimator,
                          'pmc_bridge': found.get('pmc_bridge', {}),
                          'predictions': [dataclasses.asdict(p) for p in predictions],
                          'chosen': chosen.name}))
    else:
        _print_identification(ident, low, high, args.ksd_margin, depths, cut_depth)
        print(f'closed-loop verification on {job.run.name} ({chosen.plants} plants: the '
              f'identified one, {args.plants} drawn about it and {len(drifted_plants(ident))} '
              'drifts of it; band: steady <= 5 N, ripple <= 25 N):')
        for prediction in predictions:
            print(f'  {prediction.line()}')
        print(f'chosen: {chosen.name}'
              + (' (no candidate holds as many plants as the uncommissioned defaults, within 1 N'
                 ' of them on the identified plant, and nearer the band: none of the identified'
                 ' settings is written)' if chosen.name == 'defaults' else ''))
        if entry is not None and chosen.name != 'defaults':
            print(entry_line)
        if estimator.get('rezero_start_in_air') and chosen.name != 'defaults':
            print(f"friction: read in {job.run.name}'s approach in air before its first cut "
                  '(force_estimator.rezero_start_in_air)')
    # a job that runs the axis faster than the air move measured the friction at
    beyond = friction_beyond_reach(ident, job)
    if beyond:
        print(f'turning-force: warning: {beyond}', file=sys.stderr)
    servo = ident.servo
    header = [
        f'turning-force identify {" ".join(map(str, args.bags))}',
        *([f'warning: {beyond}'] if beyond else []),
        f'PMC dead time {ident.dead_time_s.value * 1e3:.1f} +/- '
        f'{ident.dead_time_s.std * 1e3:.2g} ms; feed servo {servo.model} (residual '
        f'{servo.residual_rms:.3g} mm/min); K_s d {ident.ksd_n_mm.value:.0f} +/- '
        f'{ident.ksd_n_mm.std:.2g} N/mm; tau_c '
        f'{ident.process["cutting_time_constant_s"].value * 1e3:.1f} ms',
        f'smc_ksd bounds: K_s d / (1 + m) to K_s d (1 + m), m = max({args.ksd_margin:g}, 3 sd)'
        f', scaled to depths {depths[0]:g}-{depths[1]:g} mm; cutting exponent g '
        f'{ident.process["cutting_exponent"].value:.3f}',
        f'For jobs cutting {depths[0]:g}-{depths[1]:g} mm deep (identify --depths-mm or --job): '
        'another depth range, identify again',
        *(f'predicted {p.line()}' for p in predictions),
        *([entry_line] if entry is not None and chosen.name != 'defaults' else []),
        f'{PREDICTION} ' + json.dumps({'law': chosen.name, 'steady_n': chosen.steady_n,
                                        'mean_n': chosen.mean_n, 'ripple_n': chosen.ripple_n,
                                        'in_band': chosen.in_band, 'plants': chosen.plants}),
        'Load with: turning-force run EXPERIMENT.yaml --params THIS_FILE',
        '       or: ros2 run ... --params-file EXPERIMENT.yaml --params-file THIS_FILE']
    if args.tool is not None:
        _write_tool_section(args, sections)
        return 0
    text = format_parameters(sections, header)
    _emit_parameters(text, args)
    return 0


def _tool_limits(args: argparse.Namespace) -> list[str]:
    """``identify --tool N``: the tool's reference and its bridge limits, from its section of
    the tools file ``--out`` where it has one, as assignments: the job is verified, and the
    entry feed judged, on what the tool cuts with."""
    from turning_force.core.tools import load_tools_file

    path = Path(args.out) if args.out else None
    if path is None or not path.exists():
        return []
    section = load_tools_file(path).get(args.tool, {})
    reference = section.get('force_controller', {}).get('reference_force_n')
    return [*([f'force_controller.reference_force_n={reference!r}'] if reference else []),
            *(f'pmc_bridge.{key}={value!r}'
              for key, value in section.get('pmc_bridge', {}).items())]


def _write_tool_section(args: argparse.Namespace,
                        sections: Mapping[str, Mapping[str, Any]]) -> None:
    """``identify --tool N --out TOOLS_FILE``: the identified controller settings as tool N's
    section of a tools file (core/tools.py), its reference, its other part (the bridge's
    limits) and the other tools' sections kept, but for the entry feed where identify lowered
    it for the tool's depths (:func:`~turning_force.core.verification.entry_override_pct`),
    all of which the verification cut with (:func:`_tool_limits`). The estimator's
    settings are the machine's (its feed drive), not a tool's: identify without --tool writes
    them."""
    from turning_force.core.tools import load_tools_file, save_tool_section

    if not args.out:
        raise TurningForceError(f'identify --tool {args.tool}: --out TOOLS_FILE is needed (the '
                                'tools file whose section for the tool it writes)')
    path = Path(args.out)
    section = load_tools_file(path).get(args.tool, {}) if path.exists() else {}
    # the tool's reference is the shop's choice (or its teach-in's), not a result: kept
    kept = {key: value for key, value in section.get('force_controller', {}).items()
            if key == 'reference_force_n'}
    section['force_controller'] = {**kept, **{
        name: value if isinstance(value, (str, bool)) else float(f'{float(value):.6g}')
        for name, value in sections['force_controller'].items()}}
    if 'pmc_bridge' in sections:   # the tool's entry feed, beside its other limits
        section['pmc_bridge'] = {**section.get('pmc_bridge', {}), **sections['pmc_bridge']}
    save_tool_section(path, args.tool, section)
    if not args.json:
        print(f'tool {args.tool}: its section written to {path} (the other tools kept); the '
              "force_estimator settings are the machine's: identify without --tool writes them")


PREDICTION = 'prediction:'   # the header line `identify` writes and `run --params` reads


def _verification_job(args: argparse.Namespace, commissioning: Any,
                      depths: tuple[float, float]) -> Any:
    """The job the settings are verified on: --job's file, or the commissioning machine
    regulating a three-step job over --depths-mm (1 s apart from the reference's settling,
    four seconds a depth, as Park's Fig. 8)."""
    from turning_force.core.experiment import load_experiment

    if args.job:
        return load_experiment(args.job)
    low, high = depths
    return commissioning.with_sets([
        'force_controller.controller=smc', 'experiment.name=steps_over_depths_mm',
        'lathe_sim.depth_times_s=[0.0, 4.0, 8.0]',
        f'lathe_sim.depth_mm=[{low!r}, {(low + high) / 2.0!r}, {high!r}]',
        'lathe_sim.depth_interpolation=step', 'experiment.duration_s=12.0'])


def _job_depths(args: argparse.Namespace) -> tuple[float, float]:
    """The job's depth range: --depths-mm, or the --job file's cutting depths. Without
    either, identification would tune to the commissioning cut's depth alone, and a job cut
    deeper or shallower sees bounds on K_s d that do not hold (issue 15: 40.8 N steady against
    1.2 N with the job's range)."""
    if args.job and args.depths_mm:
        raise TurningForceError('identify: --depths-mm or --job, not both')
    if args.job:
        from turning_force.core.experiment import load_experiment

        cut = [d for d in load_experiment(args.job).plant.depth_mm if d > 0]
        if not cut:
            raise TurningForceError(f'{args.job}: lathe_sim.depth_mm: the job never cuts')
        return min(cut), max(cut)
    depths = _parse_range(args.depths_mm, '--depths-mm')
    if depths is None:
        raise TurningForceError("identify: the job's depths of cut are needed: --depths-mm "
                                'MIN:MAX or --job EXPERIMENT.yaml (the K_s d bounds and the '
                                "laws' model scale with the depth)")
    return depths


def _print_identification(ident: Any, ksd_min: float, ksd_max: float, margin: float,
                          depths: tuple[float, float] | None, cut_depth: float | None) -> None:
    def line(label: str, e: Any, scale: float = 1.0, unit: str = '', digits: int = 4) -> str:
        return (f'  {label:30s} {e.value * scale:10.{digits}g} {unit:9s} +/- '
                f'{e.std * scale:.2g}')

    print(f'{", ".join(ident.sessions)}: {ident.air_s:.1f} s of air move, {ident.cut_s:.1f} s '
          'of cut')
    servo = ident.servo
    print(f'feed servo and PMC (feed against override): {servo.model} chosen by BIC')
    for name, fit in ident.servo_candidates.items():
        print(f'    {name:13s} BIC {fit.bic:12.1f}   residual {fit.residual_rms:.3g} mm/min '
              f'({fit.samples} samples)')
    print(line('PMC dead time', servo['dead_time_s'], 1e3, 'ms'))
    if servo.model == 'first_order':
        print(line('servo time constant tau_s', servo['time_constant_s'], 1e3, 'ms'))
    else:
        print(line('servo natural frequency w_n', servo['natural_freq_rad_s'], 1.0, 'rad/s'))
        print(line('servo damping', servo['damping']))
        print(f'  {"first-order equivalent":30s} {ident.equivalent_time_constant_s * 1e3:10.4g}'
              ' ms        (2 zeta / w_n)')
    process = ident.process
    print(f'cutting process, Park Eq. 1 (force against feed in the cut): residual '
          f'{process.residual_rms:.3g} N ({process.samples} samples)')
    print(line('K_s d', process['ksd_n_mm'], 1.0, 'N/mm'))
    print(line('cutting exponent g (F ~ f^g)', process['cutting_exponent']))
    for end in ('min', 'max'):
        if f'friction_error_at_{end}_a' in process.parameters:
            print(line(f"prior's friction error at {end}", process[f'friction_error_at_{end}_a'],
                       1.0, 'A'))
    print(line('G = K_s d / N^g', process['gain_n_per_mm_min'], 1.0, 'N/(mm/min)^g'))
    if cut_depth:
        ksd = process['ksd_n_mm']
        print(f'  {"K_s (cut " + f"{cut_depth:g}" + " mm deep)":30s} {ksd.value / cut_depth:10.4g}'
              f' N/mm^2    +/- {ksd.std / cut_depth:.2g}')
    print(line('tau_c', process['cutting_time_constant_s'], 1e3, 'ms'))
    friction, model = ident.friction, ident.friction_model
    print(f'friction, Park Eq. 25 ({model.min_feed_mm_min:g}-{model.max_feed_mm_min:g} mm/min): '
          + (f'air move, residual {friction.residual_rms:.3g} A' if 'friction' not in ident.kept
             else 'kept from --prior (no air move: not separable from the cutting force)'))
    print(line(f'at {model.min_feed_mm_min:g} mm/min', friction['at_min_feed_a'], 1.0, 'A'))
    print(line(f'at {model.max_feed_mm_min:g} mm/min', friction['at_max_feed_a'], 1.0, 'A'))
    print(line('force noise (one sample, cut)', ident.force_noise_n, 1.0, 'N'))
    print(line('  of it the sensor (air move)' if ident.air_s else "  taken as the sensor's",
               ident.air_noise_n, 1.0, 'N'))
    print(line("  and the cut's own, r (+-r F)", ident.force_fluctuation, 1.0, ''))
    scaled = f', scaled to depths {depths[0]:g}-{depths[1]:g} mm' if depths else ''
    print(f'SMC bounds on K_s d: {ksd_min:.0f}-{ksd_max:.0f} N/mm (geometric about K_s d, '
          f'margin max({margin:g}, 3 sd){scaled})')


def _reproduce(args: argparse.Namespace) -> int:
    from turning_force.commands.papers import ROWS, format_table, regressions, reproduce

    rows = [r for r in ROWS if not args.experiment or r.experiment in args.experiment]
    if not rows:
        raise TurningForceError(f'--experiment {" ".join(args.experiment)}: no row runs it; '
                                f'the rows run {", ".join(sorted({r.experiment for r in ROWS}))}')
    results = reproduce(Path(args.dir), rows, args.set)
    if args.json:
        print(json.dumps({'sets': list(args.set), 'rows': [{
            'scenario': r.row.label, 'experiment': r.row.experiment, 'sets': list(r.row.sets),
            'paper': dataclasses.asdict(r.row.paper) if r.row.paper else None,
            'ours_n': r.ours_n, 'verdict': r.verdict[0], 'reason': r.verdict[1],
            'expected': r.row.expect, 'ours_from': 'simulated',
            'allowed_error_n': r.allowed_error_n, 'settled_forces_n': list(r.settled_forces_n),
            'metrics': r.metrics} for r in results]}))
    else:
        print(format_table(results))
    failed = regressions(results)
    for r in failed:
        print(f'turning-force: {r.row.label} ({r.row.experiment}) was {r.row.expect}, is worse '
              f'now: {r.verdict[1]}', file=sys.stderr)
    return 1 if failed else 0


def _describe(args: argparse.Namespace) -> int:
    from turning_force.core.catalog import describe, parameters_markdown

    if args.markdown:
        sys.stdout.write(parameters_markdown())
        return 0
    directory = Path(args.dir)
    print(describe(args.target, directory if directory.is_dir() else None))
    return 0


def _repair(args: argparse.Namespace) -> int:
    from turning_force.session.repair import repair

    result = repair(args.bag)
    if args.json:
        print(json.dumps({'session': str(result.path), 'repaired': result.repaired,
                          'recovered': result.recovered, 'recorded': result.recorded,
                          'damage': result.damage, 'summary': result.summary,
                          'kept': result.kept}))
    elif result.repaired:
        print(f'{result.path}: repaired: {result.summary}. The files it replaced are kept '
              f'beside it ({", ".join(result.kept)})')
    else:
        print(f'{result.path}: {result.summary}')
    return 0


def _pmc_check(args: argparse.Namespace) -> int:
    from turning_force.core.pmc.machine import load_machine
    from turning_force.io.pmc_check import check_pmc

    machine = load_machine(args.machine)
    if machine.modbus is None:
        raise TurningForceError(f'{args.machine}: backend.type = {machine.backend!r}: no module '
                                'to check')
    return 0 if check_pmc(machine, sys.stdout, args.control_period_s, args.dwell_s,
                          hand_back_pct=args.hand_back_pct) else 1


def _number_in(low: float, high: float, low_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [low, high] (``(low, high]`` with ``low_open``);
    argparse prints the one-line error, the value shortened."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        below = value <= low if low_open else value < low
        if not math.isfinite(value) or below or value > high:
            bracket = '(' if low_open else '['
            raise argparse.ArgumentTypeError(
                f'{short_repr(text)}: expected a finite number in {bracket}{low:g}, {high:g}]')
        return value
    return parse


def _band_n(args: argparse.Namespace) -> float:
    """The band about the reference: the experiment's ``allowed_error_n``, else the default."""
    from turning_force.core.experiment import ViewSettings

    if args.experiment:
        return load_experiment(args.experiment).run.allowed_error_n
    return ViewSettings().allowed_error_n


def _view(args: argparse.Namespace) -> int:
    from turning_force.commands.live import view

    return view(args.namespace, {'host': args.host, 'port': args.port, 'rate_hz': args.rate,
                                 'allowed_error_n': _band_n(args)})


def _watch(args: argparse.Namespace) -> int:
    from turning_force.commands.live import watch

    if args.duration is not None and not args.duration > 0:
        raise TurningForceError(f'--duration {args.duration!r}: must be positive')
    return watch(args.namespace, args.duration, _band_n(args))


# Options several commands take, by flag (``command(...)`` names them); {what}: what runs in
# parallel.
SHARED_OPTIONS: dict[str, dict[str, Any]] = {
    '--params': {'action': 'append', 'default': [], 'metavar': 'FILE', 'help': (
        'a parameters file laid over the experiment (repeatable; e.g. what identify wrote); '
        '--set applies after it')},
    '--set': {'action': 'append', 'default': [], 'metavar': 'NODE.PARAM=VALUE',
              'help': 'change one parameter (repeatable; the value is read as YAML)'},
    '--json': {'action': 'store_true', 'help': 'print one JSON object'},
    '--partial': {'action': 'store_true', 'help': (
        'read a session that misses messages (what it misses is printed) instead of refusing '
        'it')},
    '--jobs': {'type': int, 'metavar': 'N',
               'help': 'local processes for the {what} (default: one per core)'},
    '--dask': {'metavar': 'SCHEDULER_ADDRESS', 'help': (
        "run the {what} on a Dask cluster instead (pip install 'turning_force[dask]', on the "
        'workers too); on another host: tls://... with --tls-ca, --tls-cert and --tls-key')},
    '--tls-ca': {'metavar': 'FILE',
                 'help': "with --dask tls://: the CA certificate that signed the scheduler's"},
    '--tls-cert': {'metavar': 'FILE', 'help': "with --dask tls://: this client's certificate"},
    '--tls-key': {'metavar': 'FILE', 'help': 'with --dask tls://: its key'},
    '--insecure': {'action': 'store_true', 'help': (
        'allow a --dask scheduler on another host over plain tcp:// (a trusted network only: '
        'the sessions and the work travel unencrypted)')},
    '--namespace': {'default': '/', 'help': (
        "the graph's namespace, as its nodes were started with (default /)")},
    '--experiment': {'metavar': 'FILE', 'help': (
        'the experiment the graph runs: the band about the reference is its allowed_error_n')},
}
PARALLEL = ('--jobs', '--dask', '--tls-ca', '--tls-cert', '--tls-key', '--insecure')
LIVE = ('--namespace', '--experiment')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='turning-force', description=__doc__.split('\n')[0])
    commands = parser.add_subparsers(dest='command', required=True)

    def command(name: str, handler: Callable[[argparse.Namespace], int], help: str,
                *shared: str, what: str = '') -> argparse.ArgumentParser:
        """A command, its handler and the :data:`SHARED_OPTIONS` named (before its own)."""
        sub = commands.add_parser(name, help=help)
        sub.set_defaults(handler=handler)
        for flag in shared:
            options = SHARED_OPTIONS[flag]
            sub.add_argument(flag, **{**options, 'help': options['help'].format(what=what)})
        return sub

    run = command('run', _run, 'run an experiment through the graph, recorded', '--params',
                  '--set', '--json')
    run.add_argument('experiment', help='ROS 2 parameters file (config/experiments/*.yaml)')
    run.add_argument('--out', help='session folder to create (default bags/<name>_<time>)')
    run.add_argument('--core', action='store_true', help='the ROS-free core loop (recorded '
                     'as the graph records it with --out; no session without)')

    rep = command('replay', _replay, 're-run estimator and controller on sessions', '--params',
                  '--set', '--json', '--partial', *PARALLEL, what='sessions')
    rep.add_argument('bags', nargs='+', metavar='BAG',
                     help='session folder (rosbag2, MCAP); several: one row each and totals')
    rep.add_argument('--experiment', help='settings to start from, for a session that embeds '
                     'none (default: the recorded ones)')
    rep.add_argument('--publish', action='store_true',
                     help='play the sensor topics into a live graph instead (one BAG)')
    rep.add_argument('--rate', type=float, default=1.0, help='playback rate with --publish')
    rep.add_argument('--closed-loop', action='store_true',
                     help='identify the machine and run the --set settings on it in closed loop '
                     '(the force they would have caused), beside the recorded figures (one BAG)')
    rep.add_argument('--identified-from', action='append', metavar='BAG',
                     help='with --closed-loop: identify from this commissioning session '
                     '(repeatable) instead of the replayed one')

    swp = command('sweep', _sweep, 'every combination of a grid of settings, closed loop or '
                  'on a session; the best, a table and a heat map', '--params', '--set', '--json',
                  '--partial', *PARALLEL, what='points')
    swp.add_argument('experiment', nargs='?', help='ROS 2 parameters file; with --replay: '
                     'settings to start from instead of the recorded ones')
    swp.add_argument('--grid', action='append', required=True,
                     metavar='NODE.PARAM=START:STOP:N',
                     help='one axis (repeatable): START:STOP:N evenly spaced, START:STOP:Nlog '
                     'log-spaced, or v1,v2,... (values read as YAML)')
    swp.add_argument('--replay', metavar='BAG', help="open loop on this session's recorded "
                     'currents instead of the simulator')
    swp.add_argument('--metric', default='steady_mean_abs_error_n', choices=METRIC_NAMES,
                     help='what the best are ranked by (default: steady_mean_abs_error_n)')
    swp.add_argument('--top', type=int, default=5, help='how many of the best to print')
    swp.add_argument('--out', help='the whole table: .csv or .parquet')
    swp.add_argument('--figure', help='heat map of the metric over the first two axes (.png)')

    report = command('report', _report, 'the figure and metrics of a session', '--json',
                     '--partial')
    report.add_argument('bag', help='session folder (rosbag2, MCAP)')
    report.add_argument('--out', help='PNG or HTML to write (default: a PNG beside the '
                        'session)')

    cal = command('calibrate', _calibrate, 'friction (Park Eq. 25) from air-cut sessions; '
                  'with --map the current-to-force map (Eq. 26)', '--json', '--partial')
    cal.add_argument('bags', nargs='+', help='air-cut sessions, one feed each, two or more; '
                     'with --map: cuts recorded with a dynamometer on force/measured')
    cal.add_argument('--map', action='store_true', help='fit Park Eq. 26 against the '
                     'dynamometer instead')
    cal.add_argument('--axis', choices=('x', 'y', 'z'), default='z',
                     help='with --map: the WrenchStamped force component of the feed axis')
    cal.add_argument('--reference-n', type=float, default=500.0,
                     help='with --map: the reference whose bias under the recorded map is shown')
    cal.add_argument('--out', help='with --map: parameters file to write')
    cal.add_argument('--settle-s', type=float, default=0.5,
                     help='time left out at the start of each session [s]')

    ident = command('identify', _identify, "the machine's model from commissioning sessions, "
                    'as a parameters file', '--json')
    ident.add_argument('bags', nargs='+', help='sessions of the commissioning experiment (an '
                       'air move and a cut with override steps), or production cuts under '
                       'regulation (with --prior)')
    ident.add_argument('--prior', metavar='FILE',
                       help='the earlier commissioning file: what a production session cannot '
                       'identify (friction, without an air move) is kept from it')
    ident.add_argument('--out', help='parameters file to write (default: print it)')
    ident.add_argument('--cut-force-n', type=float, default=50.0,
                       help='a force estimate above this is the cut [N]')
    ident.add_argument('--ksd-margin', type=float, default=0.1,
                       help='SMC K_s d bounds: at least this fraction either side [-]')
    ident.add_argument('--depths-mm', metavar='MIN:MAX',
                       help="the job's depths of cut (required, or --job): the K_s d bounds "
                       'scale with them (K_s d is proportional to d)')
    ident.add_argument('--job', metavar='EXPERIMENT.yaml',
                       help='the job the settings are for: its depths of cut (instead of '
                       '--depths-mm)')
    ident.add_argument('--cut-depth-mm', type=float,
                       help='depth of the commissioning cut (known from a simulated session)')
    ident.add_argument('--plants', type=int, default=50,
                       help='closed-loop verification: plants drawn about the identified one')
    ident.add_argument('--tool', type=int, metavar='N',
                       help="write the controller's settings as tool N's section of the tools "
                       'file --out (docs/commissioning.md), keeping the other tools')

    command('repair', _repair, 'rebuild a session from what its MCAP holds', '--json'
            ).add_argument('bag', help='session folder (rosbag2, MCAP)')

    papers = command('reproduce', _reproduce, "the papers' scenarios beside their numbers",
                     '--set', '--json')
    papers.add_argument('--dir', default='config/experiments', help='experiment files')
    papers.add_argument('--experiment', action='append', default=[], metavar='NAME',
                        help='only the rows that run this experiment (repeatable)')

    explain = command('describe', _describe, 'what a parameter means: unit, range, default, '
                      'paper and equation, which file sets it')
    explain.add_argument('target', nargs='?', metavar='NODE | NODE.PARAM',
                         help='a node (its parameters) or one parameter (in full); none: the '
                         'nodes')
    explain.add_argument('--dir', default='config/experiments',
                         help='experiment files searched for the ones that set NODE.PARAM')
    explain.add_argument('--markdown', action='store_true',
                         help='every parameter as docs/parameters.md has them')

    check = command('pmc-check', _pmc_check, 'step the PMC module through every override '
                    'level and read each back')
    check.add_argument('machine', help='machine file (config/machines/*.yaml)')
    check.add_argument('--dwell-s', type=_number_in(0.0, 60.0), default=0.5,
                       help='time each level is held, for the operator to read it [s]')
    check.add_argument('--control-period-s', type=_number_in(0.0, 1.0, low_open=True),
                       default=0.01, help="the bridge's control period: the timeout when the "
                       'file gives none')
    check.add_argument('--hand-back-pct', type=_number_in(0.0, 100.0), default=100.0,
                       help="the bridge's hand_back_pct: the wiring's all-off level must not "
                       'exceed it')

    live = command('view', _view, "serve a running graph's topics to Foxglove or Lichtblick "
                   '(Foxglove WebSocket)', *LIVE)
    live.add_argument('--host', default='127.0.0.1', help='address to bind to (default '
                      '127.0.0.1: this machine only; 0.0.0.0: every interface, no password)')
    live.add_argument('--port', type=int, default=8765, help='TCP port (default 8765, '
                      "Foxglove's; 0: a free one, printed)")
    live.add_argument('--rate', type=float, default=0.0, metavar='HZ', help='most messages a '
                      'second on each streaming topic (default 0: every one)')

    command('watch', _watch, "a running graph's force, override, gate and alarms in the "
            'terminal', *LIVE).add_argument(
        '--duration', type=float, metavar='S', help='stop after S seconds (default: at Ctrl-C)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        code: int = args.handler(args)
    except Interrupted as exc:
        print(f'turning-force: {exc}', file=sys.stderr)
        return exc.exit_status
    except TurningForceError as exc:
        print(f'turning-force: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:   # a command that does not handle SIGINT itself
        print('turning-force: interrupted by SIGINT', file=sys.stderr)
        return 128 + signal.SIGINT
    return code


def console() -> NoReturn:
    """The ``turning-force`` command: :func:`main`, then out without the interpreter's
    teardown. A command that has finished, flushed its output and run its exit handlers has
    nothing left to tear down, and dismantling numba's and LLVM's objects one by one takes a
    fifth of a short run's wall time (0.13 s of 0.58)."""
    code = main()
    for thread in threading.enumerate():   # as the interpreter would: its threads finish
        if thread is not threading.main_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()   # logging's and the libraries' own exit handlers
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    console()
