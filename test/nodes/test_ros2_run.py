"""`ros2 run turning_force <node>` works: colcon builds the workspace against the ROS wheels, the
executable is found the way ros2run finds it, and the node starts from an experiment file.

Slow (a colcon build of the workspace, one to three minutes): run by ``make test-all``.

ros2cli is not on PyPI, so the lookup is done here with ament_index_python exactly as
``ros2run.api.get_executable_path`` does: package prefix from the ament index, then
``<prefix>/lib/<package>/<executable>``, which must be an executable file.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient
from turning_force_msgs.msg import ForceEstimate, ServoCurrents

pytestmark = pytest.mark.slow

VENV = Path(sys.prefix)
EXECUTABLES = ['lathe_sim', 'force_estimator', 'force_controller', 'pmc_bridge',
               'session_recorder', 'turning_force_graph', 'turning_force_machine', 'live_view']


@pytest.fixture(scope='module')
def workspace(tmp_path_factory, root) -> dict[str, str]:
    """colcon build of msgs + src into a fresh install space; the environment its setup.bash
    gives (on top of the venv's prefix, as /opt/ros would be on a lathe PC)."""
    base = tmp_path_factory.mktemp('ws')
    env = {**os.environ, 'AMENT_PREFIX_PATH': str(VENV), 'CMAKE_PREFIX_PATH': str(VENV),
           'PATH': f'{VENV / "bin"}:{os.environ["PATH"]}'}
    build = subprocess.run(
        [str(VENV / 'bin' / 'colcon'), '--log-base', str(base / 'log'), 'build',
         '--base-paths', str(root / 'msgs'), str(root / 'src'),
         '--build-base', str(base / 'build'), '--install-base', str(base / 'install'),
         '--cmake-args', f'-DPython3_EXECUTABLE={VENV / "bin" / "python"}',
         '-DBUILD_TESTING=OFF'],
        cwd=base, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    sourced = subprocess.run(
        ['bash', '-c', f'source {base / "install" / "setup.bash"} && env -0'],
        env=env, capture_output=True, check=True, timeout=60)
    return dict(line.split('=', 1) for line in sourced.stdout.decode().split('\0') if '=' in line)


def ros2run_executable(package: str, executable: str) -> Path:
    """What ``ros2 run`` would execute (ros2run.api.get_executable_path)."""
    prefix = Path(get_package_prefix(package))
    path = prefix / 'lib' / package / executable
    assert path.is_file() and os.access(path, os.X_OK), f'{path} is not an executable file'
    return path


def test_ament_index_finds_every_node_of_the_colcon_install(workspace, monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', workspace['AMENT_PREFIX_PATH'])
    install = Path(workspace['AMENT_PREFIX_PATH'].split(':')[0]).parent
    for exe in EXECUTABLES:
        path = ros2run_executable('turning_force', exe)
        assert install in path.parents, f'{path} is not from the colcon install {install}'
    assert Path(get_package_prefix('turning_force_msgs')).parent == install


def test_node_starts_from_an_experiment_file_and_publishes(workspace, monkeypatch, context,
                                                           executor, spin_until,
                                                           experiments_dir):
    monkeypatch.setenv('AMENT_PREFIX_PATH', workspace['AMENT_PREFIX_PATH'])
    exe = ros2run_executable('turning_force', 'force_estimator')
    namespace = f'/ros2run_{os.getpid()}'
    params = experiments_dir / 'hwang1990_example1.yaml'
    child = subprocess.Popen(
        [str(exe), '--ros-args', '--params-file', str(params), '-r', f'__ns:={namespace}'],
        env=workspace, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        node = Node('ros2run_probe', context=context)
        executor.add_node(node)
        received: list[ForceEstimate] = []
        node.create_subscription(ForceEstimate, f'{namespace}/force/estimate',
                                 received.append, 10)
        publisher = node.create_publisher(ServoCurrents, f'{namespace}/servo/currents', 10)
        block = ServoCurrents(sample_period_s=1e-3, phase_u_a=[0.0] * 10,
                              phase_v_a=[1.0] * 10, rotor_angle_rad=[0.0] * 10,
                              feed_rate_mm_min=[120.0] * 10)
        stamp = [0]

        def published_and_heard() -> bool:
            if not received:
                stamp[0] += 1
                block.header.stamp.sec = stamp[0]
                publisher.publish(block)
            return bool(received)

        assert spin_until(published_and_heard, timeout_s=30.0), child.stdout.read()
        estimate = received[0]
        assert estimate.status == ForceEstimate.STATUS_OK
        # i_u = 0, i_v = 1 A at angle 0: i_q = 2 / sqrt(3) A; less Eq. 25 friction at
        # 120 mm/min and Eq. 26's offset, over its slope.
        friction = 0.6 + (0.35 - 0.6) / 294**2 * (120 - 6) ** 2
        expected = (2 / 3**0.5 - friction + 0.12432) / 0.00629
        assert estimate.force_n == pytest.approx(expected, rel=1e-6)

        # The parameters came from the experiment file (a value that is not the default).
        client = AsyncParameterClient(node, f'{namespace}/force_estimator')
        assert client.wait_for_services(timeout_sec=10.0)
        future = client.get_parameters(['kalman_accel_noise_n_s2'])
        assert spin_until(future.done)
        assert future.result().values[0].double_value == 1.0e6
    finally:
        child.send_signal(signal.SIGINT)
        assert child.wait(timeout=20) == 0
