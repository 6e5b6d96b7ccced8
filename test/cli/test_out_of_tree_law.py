"""A control law from another package (test/plugin/relay_law: one module and its pyproject.toml)
installed beside ours, found through the ``turning_force.laws`` entry point, and run compiled in
``run --core`` and in the node graph, with its own settings as force_controller parameters.

The distribution is installed with pip into a folder of its own that the runs put on their
path: the package's environment, and so every other test's set of laws, stays as it is.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

PLUGIN = Path(__file__).resolve().parents[1] / 'plugin' / 'relay_law'
SHORT = 'experiment.duration_s=6.0'


@pytest.fixture(scope='module')
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The relay law's distribution, built and installed (no index, no download)."""
    root = tmp_path_factory.mktemp('relay')
    source = shutil.copytree(PLUGIN, root / 'source')
    subprocess.run([sys.executable, '-m', 'pip', 'install', '--quiet', '--no-deps', '--no-index',
                    '--no-build-isolation', '--target', str(root / 'site'), str(source)],
                   check=True, timeout=300)
    assert list((root / 'site').glob('turning_force_relay-*.dist-info/entry_points.txt'))
    return root / 'site'


def turning_force(site: Path, *args: str) -> subprocess.CompletedProcess[str]:
    # numba's dispatchers (TURNING_FORCE_AOT=0): the relay's kernel is not compiled ahead of
    # time as well (5-15 s more; the module's own tests are test_kernel's).
    env = {**os.environ, 'TURNING_FORCE_AOT': '0',
           'PYTHONPATH': os.pathsep.join(filter(None, [str(site), os.environ.get('PYTHONPATH')]))}
    return subprocess.run([sys.executable, '-c', PROGRAM, *args], env=env, capture_output=True,
                          text=True, timeout=600, check=False)


# The command line, then proof that the law's step ran compiled: it is under numba's hand (its
# dispatcher, or deferred until Python calls it; a plain function has no py_func), and the
# entry point that called it (the core loop's, or the controller's in the graph) was compiled
# for its signature: by numba ('1' signature) or ahead of time ('ahead'), into the cache folder
# named for the installed laws' sources, the relay's among them. Compiled code calls only
# compiled code: numba refuses a Python function in it.
PROGRAM = """
import sys
from turning_force import cli
cli.main(sys.argv[1:])
import turning_force_relay
from turning_force.core import aot, codecache
from turning_force.core.control import update
from turning_force.core.kernel import loops


def compiled(entry):
    return 'ahead' if isinstance(entry, aot.Checked) else len(entry.signatures)


print('relay step:', 'compiled' if hasattr(turning_force_relay.step, 'py_func') else 'Python')
print('keyed on:', ' '.join(name for name, _, _ in codecache.installed_laws()))
print('compiled: run_core', compiled(loops.run_core), 'control_step',
      compiled(update.control_step))
"""
COMPILED = 'relay step: compiled'


def metrics(stdout: str) -> dict[str, float]:
    return {m[1]: float(m[2]) for m in re.finditer(r'^\s+([a-z_]+_(?:n|s|fraction))\s+(\S+)$',
                                                     stdout, re.MULTILINE)}


# One test for both paths: with the relay installed the kernel's cache folder is a new one,
# and the first run compiles the whole kernel (about 50 s here); two tests on two workers would
# each compile it at once.
def test_the_relay_runs_compiled_in_the_core_loop_and_the_node_graph_with_its_settings(
        site, fig8, tmp_path):
    run = turning_force(site, 'run', str(fig8), '--core', '--set', SHORT,
                        '--set', 'force_controller.controller=relay')
    assert run.returncode == 0, run.stderr[-3000:]
    assert COMPILED in run.stdout and re.search(r'compiled: run_core (1|ahead) ', run.stdout)
    assert 'keyed on: relay' in run.stdout
    regulated = metrics(run.stdout)
    # The relay's band is 20 N and the four-bit table moves the force by about 50 N a level at
    # 2 mm: the force stays within a band and half a level of the reference, about 45 N, in
    # mean, and is never pinned at an end of the table.
    assert regulated['steady_mean_abs_error_n'] < 45.0
    assert regulated['reachable_fraction'] == 1.0
    # Its settings reach its compiled step: a band wider than any error never moves the feed.
    held = turning_force(site, 'run', str(fig8), '--core', '--set', SHORT,
                         '--set', 'force_controller.controller=relay',
                         '--set', 'force_controller.relay_band_n=10000.0')
    assert held.returncode == 0, held.stderr[-3000:]
    assert metrics(held.stdout)['override_changes_per_s'] == 0.0
    assert regulated['override_changes_per_s'] > 0.0

    # In the node graph: the controller's step compiled for it, and its settings recorded.
    session = tmp_path / 'relay'
    run = turning_force(site, 'run', str(fig8), '--set', SHORT,
                        '--set', 'force_controller.controller=relay',
                        '--set', 'force_controller.relay_band_n=15.0', '--out', str(session))
    assert run.returncode == 0, run.stderr[-3000:]
    assert COMPILED in run.stdout and re.search(r' control_step (1|ahead)$', run.stdout,
                                                re.MULTILINE)
    assert metrics(run.stdout)['steady_mean_abs_error_n'] < 45.0
    metadata = yaml.safe_load((session / 'metadata.yaml').read_text())
    custom = metadata['rosbag2_bagfile_information']['custom_data']
    controller = json.loads(custom['turning_force.parameters_json'])['force_controller']
    assert controller['controller'] == 'relay' and controller['relay_band_n'] == 15.0


def test_without_the_distribution_the_law_is_unknown_and_says_which_are(fig8):
    run = subprocess.run([sys.executable, '-c', PROGRAM, 'run', str(fig8), '--core',
                          '--set', 'force_controller.controller=relay'],
                         capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode != 0
    assert "force_controller.controller = 'relay': expected one of smc," in run.stderr


DESCRIBE = """
import sys
from turning_force import cli
from turning_force.core.catalog import missing_metadata, parameters_markdown
sys.exit(cli.main(sys.argv[1:]) or len(missing_metadata()) + 10 * ('relay_band_n' in
         parameters_markdown()))
"""


def test_describe_explains_an_installed_law_and_the_docs_keep_to_ours(site):
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(
        filter(None, [str(site), os.environ.get('PYTHONPATH')]))}
    run = subprocess.run([sys.executable, '-c', DESCRIBE, 'describe',
                          'force_controller.relay_band_n'], env=env, capture_output=True,
                         text=True, timeout=300, check=False)
    # Exit 0: the law's settings carry text, unit and range (missing_metadata() is empty),
    # and docs/parameters.md, which documents our laws, does not take them in.
    assert run.returncode == 0, run.stdout + run.stderr[-3000:]
    assert 'unit:     N' in run.stdout and 'range:    [0, 100000] N' in run.stdout
    assert 'read by the relay law' in run.stdout
