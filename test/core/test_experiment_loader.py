"""Experiment files a shop will bring: every bad one is one ConfigError naming the file, the key
and the value, never a traceback from below and never a value silently dropped."""

import re

import pytest
import yaml
from hypothesis import HealthCheck, Phase, event, example, find, given, settings
from hypothesis import strategies as st

from turning_force.core.errors import ConfigError
from turning_force.core.experiment import (
    OTHER_SECTIONS,
    SETTINGS_OF,
    SHARED,
    Experiment,
    build_experiment,
    load_experiment,
    parse_experiment,
    parse_set,
)
from turning_force.core.overlay import read_parameters
from turning_force.core.pmc.machine import load_machine
from turning_force.core.settings import INT64_MAX


def write(tmp_path, data: bytes | str):
    path = tmp_path / 'exp.yaml'
    if isinstance(data, str):
        data = data.encode()
    path.write_bytes(data)
    return path


def section(node: str, body: str) -> str:
    return f'{node}:\n  ros__parameters:\n{body}'


@pytest.mark.parametrize(('data', 'message'), [
    # Not UTF-8 (a file saved in Latin-1 on a shop PC): where, not a UnicodeDecodeError.
    (b'/**/experiment:\n  ros__parameters:\n    description: Stahl \xfc\n',
     'not UTF-8 text: byte 0xfc on line 3'),
    # A key twice in one mapping: YAML would keep the last one without a word.
    (section('lathe_sim', '    seed: 1\n    seed: 2\n'),
     "line 4, column 5: duplicate key 'seed' (first on line 3)"),
    ('lathe_sim:\n  ros__parameters: {seed: 1, seed: 2}\n', "duplicate key 'seed'"),
    (section('/**/lathe_sim', '    seed: 1\n') + section('/**/lathe_sim', '    seed: 2\n'),
     "line 4, column 1: duplicate key '/**/lathe_sim' (first on line 1)"),
    ('lathe_sim:\n  ros__parameters: {seed: 1}\n  ros__parameters: {seed: 2}\n',
     "line 3, column 3: duplicate key 'ros__parameters' (first on line 2)"),
    # Two sections of one node, the same key in both.
    (section('/**/lathe_sim', '    seed: 1\n') + section('lathe_sim', '    seed: 2\n'),
     'lathe_sim: seed is set under /**/lathe_sim already; one value per parameter'),
    # Integers a ROS parameter cannot hold (int64), and ones a float cannot.
    (section('lathe_sim', f'    seed: {2**63}\n'),
     f'lathe_sim.seed = {2**63}: outside the 64-bit range of a ROS integer parameter'),
    (section('lathe_sim', f'    seed: {10**400}\n'), 'lathe_sim.seed = 1000'),
    (section('lathe_sim', '    seed: -1\n'),
     r'lathe_sim.seed = -1: outside [0, 9223372036854775807]'),
    (section('lathe_sim', f'    spindle_speed_rpm: {10**400}\n'),
     'lathe_sim.spindle_speed_rpm = 1000'),
    # The name becomes a file name under bags/: nothing that leaves it.
    (section('experiment', '    name: ../../x\n'),
     "experiment.name = '../../x': must be a plain file name"),
    (section('experiment', '    name: a/b\n'), "experiment.name = 'a/b': must be a plain"),
    (section('experiment', "    name: '..'\n"), "experiment.name = '..': must be a plain"),
    (section('experiment', "    name: ''\n"), "experiment.name = '': must be a plain"),
    # The recorder's section is declared like the others: a typo is refused.
    (section('/**/session_recorder', '    flush_periodd_s: 1.0\n'),
     'session_recorder.flush_periodd_s = 1.0: unknown parameter; known: capture_parameters, '
     'experiment_file, flush_period_s, output_dir'),
    (section('session_recorder', '    flush_period_s: 0.0\n'),
     r'session_recorder.flush_period_s = 0.0: outside (0, 3600] s'),
    # Text PyYAML's constructors choke on below the YAMLError family.
    (section('lathe_sim', '    seed: !!int abc\n'), 'not valid YAML: ValueError'),
    (section('experiment', '    description: 2024-13-45\n'), 'not valid YAML: ValueError'),
])
def test_bad_file_is_one_config_error_naming_file_and_key(tmp_path, data, message):
    path = write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        load_experiment(path)
    text = str(info.value)
    assert text.startswith(f'{path}: ') and message in text, text
    assert '\n' not in text


def test_the_largest_ros_integer_is_a_seed(tmp_path):
    e = load_experiment(write(tmp_path, section('lathe_sim', f'    seed: {INT64_MAX}\n')))
    assert e.plant.seed == 2**63 - 1


def test_a_merge_key_may_be_overridden(tmp_path):
    # '<<' merges a mapping whose keys the section may then set again: not a duplicate.
    e = load_experiment(write(tmp_path, section(
        'lathe_sim', '    <<: &base {seed: 3, current_noise_a: 0.01}\n    seed: 4\n')))
    assert e.plant.seed == 4 and e.plant.current_noise_a == 0.01


def test_a_set_value_with_a_duplicate_key_is_refused():
    with pytest.raises(ConfigError, match=r"--set 'lathe_sim.seed=\{a: 1, a: 2\}'.*duplicate"):
        parse_set('lathe_sim.seed={a: 1, a: 2}')


# --- any input: a ConfigError or a valid experiment, never another exception -------------

FIELDS = {name: sorted(kind.fields()) for name, kind in {**SETTINGS_OF, **OTHER_SECTIONS}.items()}
ALL_FIELDS = sorted({f for names in FIELDS.values() for f in names})

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), st.integers(-10, 10_000),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(0.0, 2_000.0),
    st.text(max_size=12), st.sampled_from(['smc', 'pi', 'kalman', 'fanuc_0t_4bit', 'ideal',
                                           'step', 'first_order', 'simulated']))
values = st.one_of(scalars, st.lists(scalars, max_size=4),
                   st.dictionaries(st.text(max_size=5), scalars, max_size=2))


def params(names: list[str]) -> st.SearchStrategy[dict]:
    keys = st.one_of(st.sampled_from(names), st.text(max_size=8), st.integers())
    return st.dictionaries(keys, values, max_size=4)


node_keys = st.one_of(
    st.sampled_from([SHARED, *(f'/**/{n}' for n in FIELDS), *FIELDS, '/lathe1/lathe_sim']),
    st.text(max_size=10), st.integers(), st.none())
bodies = st.one_of(
    st.builds(lambda p: {'ros__parameters': p}, params(ALL_FIELDS)), values)
junk_documents = st.dictionaries(node_keys, bodies, max_size=6)


def field_values(kind: type, name: str) -> st.SearchStrategy:
    """Values of one settings field: mostly of its type and near its range, some not."""
    scalar, spec = kind.fields()[name]
    default = getattr(kind(), name)
    if scalar is float:
        low = -1e6 if spec.low is None else spec.low
        high = low + 1e6 if spec.high is None else spec.high
        typed = st.one_of(st.floats(low, high), st.sampled_from([low, high]),
                          st.floats(allow_nan=True, allow_infinity=True))
    elif scalar is int:
        typed = st.one_of(st.integers(-3, 1000), st.integers())
    elif scalar is bool:
        typed = st.booleans()
    else:
        typed = st.sampled_from(spec.choices) if spec.choices else st.text(max_size=12)
    if isinstance(default, tuple):
        typed = st.lists(typed, min_size=len(default), max_size=len(default) + 1)
        default = list(default)
    return st.one_of(st.just(default), typed, typed, scalars)


def section_params(node: str) -> st.SearchStrategy[dict]:
    kind = {**SETTINGS_OF, **OTHER_SECTIONS}[node]
    names = st.lists(st.sampled_from(FIELDS[node]), unique=True, max_size=3)
    return names.flatmap(lambda ks: st.fixed_dictionaries(
        {k: field_values(kind, k) for k in ks}))


near_documents = st.lists(st.sampled_from(sorted(FIELDS)), unique=True, max_size=4).flatmap(
    lambda nodes: st.fixed_dictionaries(
        {f'/**/{n}': st.builds(lambda p: {'ros__parameters': p}, section_params(n))
         for n in nodes}))
documents = st.one_of(junk_documents, near_documents)

# Deterministic (derandomize), a modest count: about 0.05 s per file on 2 busy cores.
PROPERTY = settings(derandomize=True, max_examples=200, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow])


def parse_or_refuse(text: str, count: bool = True) -> Experiment | None:
    try:
        e = parse_experiment(text, 'prop.yaml')
    except ConfigError as exc:
        message = str(exc)
    else:
        message = ''
    if message:
        assert message.startswith('prop.yaml: ') and '\n' not in message
        if count:
            event('refused')
        return None
    assert isinstance(e, Experiment)
    if count:
        event('valid')
    # Valid: every value is in its declared range, and what the run would record loads back
    # to the same settings.
    again = build_experiment('again', e.resolved_params())
    assert (again.run, again.plant, again.estimator, again.controller, again.bridge) == (
        e.run, e.plant, e.estimator, e.controller, e.bridge)
    return e


@PROPERTY
@given(documents)
@example({'/**': {'ros__parameters': {1: 2.0, 'b': 3.0}}})   # keys sorted for the message
@example({'/**/lathe_sim': {'ros__parameters': {'seed': 10**400}}})
@example({'/**/lathe_sim': {'ros__parameters': {'spindle_speed_rpm': -(10**400)}}})
@example({'\n': {'ros__parameters': {}}})
def test_any_yaml_mapping_is_an_experiment_or_a_config_error(document):
    try:
        text = yaml.safe_dump(document, allow_unicode=True)
    except yaml.YAMLError:   # keys PyYAML cannot write (none expected): nothing to parse
        return
    parse_or_refuse(text)


@PROPERTY
@given(st.text(max_size=200))
def test_any_text_is_an_experiment_or_a_config_error(text):
    parse_or_refuse(text)


@settings(PROPERTY, max_examples=100)
@given(st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 8), st.text(max_size=6)),
                min_size=1, max_size=3))
def test_any_edit_of_a_shipped_file_is_an_experiment_or_a_config_error(fig8, edits):
    # Near-valid text: Fig. 8's file with a few characters replaced at random places.
    text = fig8.read_text()
    for where, cut, insert in edits:
        at = round(where * len(text))
        text = text[:at] + insert + text[at + cut:]
    parse_or_refuse(text)


@settings(PROPERTY, max_examples=100)
@given(st.sampled_from(ALL_FIELDS), st.sampled_from(sorted(FIELDS)), values)
def test_any_set_is_an_experiment_or_a_config_error(field, node, value):
    base = parse_experiment('{}', 'prop.yaml')
    text = f'{node}.{field}={yaml.safe_dump(value, default_flow_style=True).strip()}'
    try:
        e = base.with_sets([text])
    except ConfigError as exc:
        message = str(exc)
    else:
        assert isinstance(e, Experiment)
        return
    assert message.startswith('--set ') or ' = ' in message, message
    assert '\n' not in message


def test_the_mapping_strategy_reaches_valid_experiments():
    # Not only refusals: the strategy finds files with settings in them that load.
    found = find(documents, lambda d: any(isinstance(b, dict) and b.get('ros__parameters')
                                          for b in d.values())
                 and parse_or_refuse(yaml.safe_dump(d), count=False) is not None,
                 settings=settings(derandomize=True, max_examples=500, database=None,
                                   phases=[Phase.generate]))   # the first found, unshrunk
    assert parse_or_refuse(yaml.safe_dump(found), count=False) is not None


def test_the_other_yaml_files_are_read_the_same_way(tmp_path, experiments_dir):
    # --params overlays and machine files: UTF-8, each key once, one line naming the file.
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(section('force_controller', '    reference_force_n: 400.0\n'
                                                   '    reference_force_n: 450.0\n'))
    with pytest.raises(ConfigError, match=re.escape(
            f"{overlay}: not valid YAML: line 4, column 5: duplicate key 'reference_force_n'")):
        read_parameters(overlay)
    text = (experiments_dir.parent / 'machines' / 'fanuc_0t.yaml').read_text()
    machine = tmp_path / 'machine.yaml'
    machine.write_bytes(text.replace('description: FANUC', 'description: Drehbank \u00fc FANUC')
                        .encode('latin-1'))
    line = text.splitlines().index(next(t for t in text.splitlines()
                                        if t.startswith('description:'))) + 1
    with pytest.raises(ConfigError, match=re.escape(
            f'{machine}: not UTF-8 text: byte 0xfc on line {line}')):
        load_machine(machine)
    machine.write_text(text + 'name: fanuc_0t_again\n')
    with pytest.raises(ConfigError, match=f"{machine}: not valid YAML: .*duplicate key 'name'"):
        load_machine(machine)


def test_settings_of_the_same_parameters_are_built_once_a_value_of_another_type_afresh(fig8):
    # The commissioning's verification builds a thousand experiments that differ in the
    # controller's section alone: the other sections' settings (frozen) are built once.
    base = load_experiment(fig8)
    a = base.with_sets(['force_controller.oscillation_swings=4'])
    b = base.with_sets(['force_controller.oscillation_swings=4'])
    c = base.with_sets(['force_controller.oscillation_swings=5'])
    assert a.controller is b.controller and a.estimator is b.estimator is c.estimator
    assert c.controller.oscillation_swings == 5 and a.controller.oscillation_swings == 4
    # 4, 4.0 and true are equal to Python, not to an int field: the built 4 serves neither.
    for value, kind in (('4.0', 'float'), ('true', 'bool')):
        with pytest.raises(ConfigError, match=f'oscillation_swings = .*expected int, got {kind}'):
            base.with_sets([f'force_controller.oscillation_swings={value}'])
