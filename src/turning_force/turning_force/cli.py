"""The ``turning-force`` command.

- ``run EXPERIMENT.yaml [--set node.param=value ...] [--json]``: one experiment on the
  simulator, metrics printed.
- ``reproduce [--dir config/experiments] [--json]``: the papers' scenarios beside the papers'
  numbers.

Errors in the user's input (a bad file, key or value) print one line naming it and exit 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from turning_force.core.errors import TurningForceError
from turning_force.core.experiment import load_experiment
from turning_force.core.metrics import METRIC_NAMES
from turning_force.core.simulate import simulate
from turning_force.papers import format_table, reproduce

__all__ = ['main']


def _run(args: argparse.Namespace) -> int:
    experiment = load_experiment(args.experiment).with_sets(args.set)
    result = simulate(experiment)
    if args.json:
        print(json.dumps({'experiment': experiment.run.name, 'source': experiment.source,
                          'metrics': result.metrics}))
        return 0
    print(f'{experiment.run.name}: {experiment.run.description}')
    if experiment.run.paper_figure:
        paper = experiment.run.paper_steady_mean_abs_error_n
        print(f'  reproduces {experiment.run.paper_figure}'
              + (f' (paper: {paper:g} N average tracking error)' if paper else ''))
    for name in (*METRIC_NAMES, 'realtime_factor'):
        print(f'  {name:26s} {result.metrics[name]:10.3f}')
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    results = reproduce(Path(args.dir))
    if args.json:
        print(json.dumps({'rows': [{'scenario': r.row.label, 'experiment': r.row.experiment,
                                    'sets': list(r.row.sets), 'paper': r.row.paper,
                                    'allowed_error_n': r.allowed_error_n,
                                    'settled_forces_n': list(r.settled_forces_n),
                                    'metrics': r.metrics} for r in results]}))
    else:
        print(format_table(results))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='turning-force', description=__doc__.split('\n')[0])
    commands = parser.add_subparsers(dest='command', required=True)
    run = commands.add_parser('run', help='run an experiment on the simulator')
    run.add_argument('experiment', help='ROS 2 parameters file (config/experiments/*.yaml)')
    run.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                     help='change one parameter (repeatable; the value is read as YAML)')
    run.add_argument('--json', action='store_true', help='print one JSON object')
    run.set_defaults(handler=_run)
    rep = commands.add_parser('reproduce', help="the papers' scenarios beside their numbers")
    rep.add_argument('--dir', default='config/experiments', help='experiment files')
    rep.add_argument('--json', action='store_true', help='print one JSON object')
    rep.set_defaults(handler=_reproduce)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        code: int = args.handler(args)
    except TurningForceError as exc:
        print(f'turning-force: {exc}', file=sys.stderr)
        return 2
    return code


if __name__ == '__main__':
    sys.exit(main())
