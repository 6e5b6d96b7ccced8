"""The graph's executables as the machine PC starts them, in processes of their own (for the
tests of the wall-clock graph and of the live views that join it)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

BIN = Path(sys.prefix) / 'bin'


def start(executable: str, namespace: str, params: Path, *extra: str) -> subprocess.Popen[str]:
    """``executable --ros-args --params-file params -r __ns:=namespace extra...``, its output
    (stdout and stderr) on one pipe."""
    return subprocess.Popen(
        [str(BIN / executable), '--ros-args', '--params-file', str(params),
         '-r', f'__ns:={namespace}', *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(process: subprocess.Popen[str]) -> str:
    """SIGINT, as Ctrl-C does; its output once it has exited, cleanly (asserted)."""
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=30)
    assert process.returncode == 0, output
    return output


def session_params(path: Path, bag: Path) -> Path:
    """A params file that arms the bridge and records to ``bag`` (node-scoped values, as on
    the lathe PC), written to ``path``."""
    path.write_text(f'/**/pmc_bridge:\n  ros__parameters: {{armed: true}}\n'
                    f'/**/session_recorder:\n  ros__parameters: {{output_dir: {bag}}}\n')
    return path
