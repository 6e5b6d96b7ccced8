"""Bad settings are rejected on construction with a ConfigError naming the key and the value."""

import math
import re
import textwrap

import pytest

from turning_force.core.control import ControllerSettings
from turning_force.core.errors import ConfigError
from turning_force.core.estimation.settings import EstimatorSettings
from turning_force.core.experiment import RunSettings, load_experiment, parse_set
from turning_force.core.plant.settings import PlantSettings


@pytest.mark.parametrize(('kind', 'key', 'value', 'match'), [
    (PlantSettings, 'servo_time_constant_s', math.nan, 'must be finite'),
    (PlantSettings, 'spindle_speed_rpm', math.inf, 'must be finite'),
    (PlantSettings, 'servo_time_constant_s', 0.0, r'outside \(0, 10\] s'),
    (PlantSettings, 'servo_time_constant_s', -0.17, r'outside \(0, 10\] s'),
    (PlantSettings, 'sample_rate_hz', 0.0, 'outside'),
    (RunSettings, 'control_period_s', 0.0, 'outside'),
    (RunSettings, 'control_period_s', -0.01, 'outside'),
    (ControllerSettings, 'model_cutting_time_constant_s', 0.0, 'outside'),
    (ControllerSettings, 'controller', 'fuzzy',
     'expected one of smc, adaptive, adaptive_pp, adaptive_smc, mpc, pi'),
    (EstimatorSettings, 'force_filter', 'median', 'expected one of lowpass, kalman'),
    (ControllerSettings, 'reference_force_n', -500.0, 'outside'),
])
def test_bad_value_names_key_and_value(kind, key, value, match):
    with pytest.raises(ConfigError, match=match) as info:
        kind(**{key: value})
    assert f'{kind.SECTION}.{key} = {value!r}' in str(info.value)


@pytest.mark.parametrize(('changes', 'bound'), [
    ({'smc_lambda_per_s': 20.5}, 'Eq. 24'),                    # 100 Hz sampling: lambda <= 20
    ({'smc_lambda_per_s': 11.0, 'control_period_s': 0.02}, 'Eq. 24'),
    ({'smc_lambda_per_s': 5.0, 'smc_unmodeled_delay_s': 0.08}, 'Eq. 23'),  # 1 / 0.24 = 4.17
    ({'smc_lambda_per_s': 15.0, 'smc_resonance_hz': 7.0}, 'Eq. 22'),      # 2 pi 7 / 3 = 14.7
])
def test_lambda_above_parks_bounds_is_rejected(changes, bound):
    with pytest.raises(ConfigError, match=rf'force_controller.smc_lambda_per_s = .*{bound}'):
        ControllerSettings(**changes)


def test_lambda_on_the_bound_is_accepted():
    assert ControllerSettings(smc_lambda_per_s=20.0).lambda_bound_per_s()[0] == pytest.approx(20)


def test_types_are_checked_not_coerced_silently():
    with pytest.raises(ConfigError, match=r'lathe_sim.seed = 1.5: expected int'):
        PlantSettings.from_params({'seed': 1.5})
    with pytest.raises(ConfigError, match='expected float, got bool'):
        PlantSettings.from_params({'spindle_speed_rpm': True})
    with pytest.raises(ConfigError, match=r'write 1.0e\+6'):
        EstimatorSettings.from_params({'kalman_accel_noise_n_s2': '1e6'})
    assert PlantSettings.from_params({'spindle_speed_rpm': 600}).spindle_speed_rpm == 600.0


def test_unknown_key_is_an_error_listing_the_known_ones():
    with pytest.raises(ConfigError, match=r'lathe_sim.spindle_rpm = 600: unknown parameter; '
                                          r'known: .*spindle_speed_rpm'):
        PlantSettings.from_params({'spindle_rpm': 600})


def test_depth_profile_rules():
    with pytest.raises(ConfigError, match=r'depth_mm .* needs one value per depth_times_s'):
        PlantSettings(depth_times_s=(0.0, 4.0), depth_mm=(1.0,))
    with pytest.raises(ConfigError, match=r'depth_times_s .* strictly increasing'):
        PlantSettings(depth_times_s=(0.0, 4.0, 4.0), depth_mm=(1.0, 2.0, 3.0))
    with pytest.raises(ConfigError, match=r'depth_mm = \(1.0, -2.0\): outside'):
        PlantSettings(depth_times_s=(0.0, 4.0), depth_mm=(1.0, -2.0))


def write(tmp_path, text):
    path = tmp_path / 'exp.yaml'
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize(('text', 'match'), [
    ('lathe_sim: [1, 2', 'not valid YAML'),
    ('- 1\n- 2\n', 'expected a mapping of node names'),
    ('lathe_sim:\n  spindle_speed_rpm: 600\n', 'lathe_sim: expected a ros__parameters mapping'),
    ('lathe_simm:\n  ros__parameters: {}\n', 'lathe_simm: unknown node; known:'),
    ('lathe_sim:\n  ros__parameters: {spindle_speed_rpm: .nan}\n',
     'lathe_sim.spindle_speed_rpm = nan: must be finite'),
    ('/**:\n  ros__parameters: {spindle_sped_rpm: 600.0}\n',
     r"\['spindle_sped_rpm'\]: no node declares"),
    ('lathe_sim:\n  ros__parameters: {sample_rate_hz: 1234.5}\n',
     'must span a whole number of samples'),
    ('force_controller:\n  ros__parameters: {override_table: ideal}\n',
     'force_controller.override_table = .ideal.: differs from pmc_bridge'),
])
def test_bad_experiment_files_name_the_file_and_key(tmp_path, text, match):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as info:
        load_experiment(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=re.escape(f'{tmp_path / "nope.yaml"}: cannot read')):
        load_experiment(tmp_path / 'nope.yaml')


def test_shared_parameters_reach_every_node_that_declares_them(tmp_path):
    path = write(tmp_path, """
        /**:
          ros__parameters: {spindle_speed_rpm: 900.0, control_period_s: 0.005}
        /lathe1/lathe_sim:
          ros__parameters: {seed: 4}
    """)
    e = load_experiment(path)
    assert e.plant.spindle_speed_rpm == e.controller.spindle_speed_rpm == 900.0
    assert e.run.control_period_s == e.bridge.control_period_s == 0.005
    assert e.plant.seed == 4 and e.plant.samples_per_block == 5


def test_set_assignments(tmp_path):
    e = load_experiment(write(tmp_path, 'experiment:\n  ros__parameters: {duration_s: 3.0}\n'))
    changed = e.with_sets(['force_controller.reference_force_n=400', 'lathe_sim.depth_mm=[2.0]',
                           'lathe_sim.depth_times_s=[0.0]'])
    assert changed.controller.reference_force_n == 400.0 and changed.plant.depth_mm == (2.0,)
    assert e.controller.reference_force_n == 500.0  # the original is untouched
    with pytest.raises(ConfigError, match=r'force_controller.smc_lambda_per_s = 50.0'):
        e.with_sets(['force_controller.smc_lambda_per_s=50.0'])
    for bad in ('reference_force_n=400', 'force_controller.reference_force_n'):
        with pytest.raises(ConfigError, match=r'expected node.param=value'):
            parse_set(bad)


def test_every_shipped_experiment_loads(experiments_dir):
    files = sorted(experiments_dir.glob('*.yaml'))
    assert len(files) >= 8
    for path in files:
        e = load_experiment(path)
        assert e.run.name == path.stem


def test_set_refuses_an_unknown_node_and_takes_shared_values(tmp_path):
    e = load_experiment(write(tmp_path, 'experiment:\n  ros__parameters: {duration_s: 3.0}\n'))
    with pytest.raises(ConfigError,
                       match=r"--set 'lathe_simm\.seed=2': unknown node 'lathe_simm'"):
        e.with_sets(['lathe_simm.seed=2'])
    shared = e.with_sets(['/**.spindle_speed_rpm=900.0'])
    assert shared.plant.spindle_speed_rpm == shared.controller.spindle_speed_rpm == 900.0


def test_pmc_bridge_armed_false_in_a_file_is_what_runs(tmp_path):
    # Before: `run` armed the bridge anyway while the recorded parameters said armed=false.
    e = load_experiment(write(tmp_path, '/**/pmc_bridge:\n  ros__parameters: {armed: false}\n'))
    assert not e.bridge.armed and not e.run.arm_bridge
    assert e.resolved_params()['pmc_bridge']['armed'] is False
    default = load_experiment(write(tmp_path, 'experiment:\n  ros__parameters: {}\n'))
    assert default.bridge.armed and default.run.arm_bridge   # a desk run regulates
    air = load_experiment(write(tmp_path, 'experiment:\n  ros__parameters: {arm_bridge: false}\n'))
    assert not air.bridge.armed


def test_arming_said_twice_must_agree(tmp_path):
    path = write(tmp_path, """
        /**/experiment:
          ros__parameters: {arm_bridge: true}
        /**/pmc_bridge:
          ros__parameters: {armed: false}
    """)
    with pytest.raises(ConfigError, match=r'pmc_bridge.armed = False: contradicts '
                                          r'experiment.arm_bridge = True'):
        load_experiment(path)


def test_the_shared_settings_are_declared_once():
    # One declaration per shared setting: the same spec object text in every section.
    from turning_force.core.control import ControllerSettings
    from turning_force.core.experiment import RunSettings
    from turning_force.core.plant.settings import PlantSettings
    from turning_force.core.pmc.settings import BridgeSettings

    for name, kinds in {
        'control_period_s': (RunSettings, PlantSettings, ControllerSettings, BridgeSettings),
        'override_table': (PlantSettings, ControllerSettings, BridgeSettings),
        'spindle_speed_rpm': (PlantSettings, ControllerSettings),
        'programmed_feed_mm_rev': (PlantSettings, ControllerSettings),
        'max_feed_force_n': (ControllerSettings, BridgeSettings),
    }.items():
        specs = {kind.fields()[name][1] for kind in kinds}
        assert len(specs) == 1, name


def test_the_reference_must_be_below_the_overload_limit(tmp_path):
    path = write(tmp_path, """
        /**/force_controller:
          ros__parameters: {reference_force_n: 2500.0}
    """)
    with pytest.raises(ConfigError, match=r'reference_force_n = 2500.0: not below '
                                          r'pmc_bridge.overload_force_n = 2000.0'):
        load_experiment(path)
