"""``turning-force describe`` and docs/parameters.md: every parameter of every node explained
from the one declaration that also makes its ROS descriptor (test/nodes/test_parameter_catalog.py
holds the nodes to it)."""

from __future__ import annotations

from pathlib import Path

import pytest

from turning_force.cli import main
from turning_force.core.catalog import (
    NODES,
    Parameter,
    describe,
    missing_metadata,
    parameters,
    parameters_markdown,
)
from turning_force.core.settings import Spec

ROOT = Path(__file__).resolve().parents[2]


def test_docs_parameters_md_is_what_the_settings_declare():
    expected = parameters_markdown()
    written = (ROOT / 'docs' / 'parameters.md').read_text()
    assert written == expected, ('docs/parameters.md is out of step with the settings: '
                                 'turning-force describe --markdown > docs/parameters.md')


def test_every_parameter_of_every_node_has_text_unit_and_range():
    assert missing_metadata() == []
    assert len(list(parameters())) == sum(len(n.fields()) for n in NODES)


@pytest.mark.parametrize(('spec', 'kind', 'problem'), [
    (Spec('Some gain of the loop', '', 0.0, 1.0), float, 'no unit'),
    (Spec('Some gain of the loop', '1/s', 0.0, None), float, 'open-ended'),
    (Spec('Some count of blocks', '-', None, 10.0), int, 'open-ended'),
    (Spec('', 's', 0.0, 1.0), float, 'no text'),
])
def test_a_parameter_without_unit_range_or_text_is_found(spec, kind, problem):
    bad = Parameter('force_controller', 'new_gain', kind, spec, kind(0.5), '', ())
    found = missing_metadata([bad])
    assert len(found) == 1 and found[0].startswith('force_controller.new_gain: ')
    assert problem in found[0]


def test_text_and_flags_need_no_unit():
    flag = Parameter('pmc_bridge', 'armed', bool, Spec('Write the override or not'), False, '',
                     ())
    assert missing_metadata([flag]) == []


def test_docs_cover_every_parameter_of_our_nodes_and_laws():
    text = (ROOT / 'docs' / 'parameters.md').read_text()
    for p in parameters():
        assert f'| `{p.name}` |' in text, p.name
    assert '| `smc_lambda_per_s` | `20` | 1/s | (0, 10000] |' in text
    assert 'Park 1998, Eqs. 10, 22-24' in text


def test_describe_one_parameter_in_full(capsys, experiments_dir):
    assert main(['describe', 'force_controller.smc_lambda_per_s', '--dir',
                 str(experiments_dir)]) == 0
    out = capsys.readouterr().out
    assert out.startswith('force_controller.smc_lambda_per_s\n')
    for line in ('unit:     1/s', 'range:    (0, 10000] 1/s', 'default:  20',
                 'changes:  while cutting', 'paper:    Park 1998, Eqs. 10, 22-24',
                 'read by the smc law', '/**/force_controller: ros__parameters:',
                 '--set force_controller.smc_lambda_per_s=VALUE'):
        assert line in out, line
    # The files that set it, with their values (park1998_fig8.yaml: smc_lambda_per_s: 20.0).
    assert 'park1998_fig8.yaml (20)' in out
    assert 'hwang1990_example1.yaml' not in out   # the adaptive SMC's file leaves it


def test_describe_a_shared_parameter_says_where_one_value_goes(experiments_dir):
    text = describe('lathe_sim.control_period_s', experiments_dir)
    assert 'once under `/**: ros__parameters:`' in text
    assert 'force_controller' in text and 'pmc_bridge' in text
    assert 'park1998_fig8.yaml (0.01)' in text   # given under /** there


def test_describe_a_dimensionless_parameter_and_a_text_one():
    text = describe('pmc_bridge.teach_fraction')
    assert 'unit:     dimensionless' in text and 'range:    (0, 2]' in text
    choice = describe('force_controller.smc_surface')
    assert 'range:    one of park1998, integral, nonlinear' in choice
    assert 'El Khalick et al. 2012' in choice


def test_describe_a_node_lists_each_of_its_parameters(capsys):
    assert main(['describe', 'pmc_bridge']) == 0
    lines = capsys.readouterr().out.splitlines()
    names = {line.split()[0] for line in lines[2:]}
    assert names == {p.name for p in parameters('pmc_bridge')}
    assert 'autostart' in names and 'overload_force_n' in names


def test_describe_without_a_target_lists_the_nodes(capsys):
    assert main(['describe']) == 0
    out = capsys.readouterr().out
    for entry in NODES:
        assert f'  {entry.node} ' in out


@pytest.mark.parametrize(('target', 'message'), [
    ('force_controler.smc_eta', "'force_controler': no such node"),
    ('force_controller.smc_lamda_per_s', 'did you mean smc_lambda_per_s'),
])
def test_describe_refuses_an_unknown_name_in_one_line(capsys, target, message):
    assert main(['describe', target]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count('\n') == 1
