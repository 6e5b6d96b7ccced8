"""rosbag2 (MCAP) sessions written and read with rosbags, our message types included.

A session is a rosbag2 folder (``metadata.yaml`` + one ``.mcap``) holding every topic of the
graph, with ``ros2msg`` schemas, so that ``ros2 bag``, Foxglove, rosbags and the mcap reader all
read it. The experiment file, the resolved parameters and the software versions are embedded as
rosbag2 custom data (in ``metadata.yaml`` and in the MCAP file's ``rosbag2`` metadata record).
"""

from __future__ import annotations

import json
import os
import platform
import time
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from turning_force.core.errors import TurningForceError

__all__ = [
    'CUSTOM_EXPERIMENT',
    'CUSTOM_PARAMETERS',
    'CUSTOM_VERSIONS',
    'BagError',
    'SessionWriter',
    'software_versions',
    'typestore',
]

CUSTOM_EXPERIMENT = 'turning_force.experiment_yaml'
CUSTOM_PARAMETERS = 'turning_force.parameters_json'
CUSTOM_VERSIONS = 'turning_force.versions_json'
MSG_PACKAGE = 'turning_force_msgs'


class BagError(TurningForceError):
    """A session folder cannot be written or read."""


def _msg_dir() -> Path:
    """Our .msg files: installed with the messages (share/), or the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(MSG_PACKAGE)) / 'msg'
        if installed.is_dir():
            return installed
    except (ImportError, LookupError, OSError, ValueError):  # no ament index here
        pass
    import turning_force_msgs  # the generated package sits in the prefix beside share/

    prefix = Path(turning_force_msgs.__file__).resolve().parents[4]
    return prefix / 'share' / MSG_PACKAGE / 'msg'


@cache
def typestore() -> Typestore:
    """The ROS 2 Kilted type store with ``turning_force_msgs`` registered from its .msg text."""
    store = get_typestore(Stores.ROS2_KILTED)
    types = {}
    for path in sorted(_msg_dir().glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'{MSG_PACKAGE}/msg/{path.stem}'))
    if not types:
        raise BagError(f'no {MSG_PACKAGE} .msg files found under {_msg_dir()}')
    store.register(types)
    return store


def software_versions() -> dict[str, str]:
    out = {'python': platform.python_version()}
    for dist in ('turning_force', 'ros-rclpy', 'numpy', 'scipy', 'rosbags'):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = 'not installed'
    return out


class SessionWriter:
    """Writes serialized messages to a new rosbag2 MCAP folder.

    rosbags closes an MCAP chunk once it holds 1 MiB; at our rates that is minutes. So that a
    killed process loses at most ``flush_period_s`` of data, the open chunk is also closed and
    the file flushed once that much wall time has passed since the last flush.
    """

    def __init__(self, path: Path, flush_period_s: float = 1.0) -> None:
        if path.exists():
            raise BagError(f'{path}: exists already; a session is never overwritten')
        self._typestore = typestore()  # before anything is created on disk
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        # zstd per chunk (rosbag2's "storage" compression): a third of the size, and every
        # MCAP reader decompresses it.
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        self._connections: dict[str, object] = {}
        self._flush_period_s = flush_period_s
        self._last_flush = time.monotonic()
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str) -> None:
        self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                               typestore=self._typestore)
        self.counts[topic] = 0

    def set_custom_data(self, key: str, value: str) -> None:
        self._writer.set_custom_data(key, value)

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        self._writer.write(self._connections[topic], timestamp_ns, data)  # type: ignore[arg-type]
        self.counts[topic] += 1
        if time.monotonic() - self._last_flush >= self._flush_period_s:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and push it to the disk."""
        storage = self._writer.storage
        if storage is not None and storage.chunk.bio.tell():  # type: ignore[attr-defined]
            storage.close_chunk()  # type: ignore[attr-defined]
            storage.bio.flush()  # type: ignore[attr-defined]
            os.fsync(storage.bio.fileno())  # type: ignore[attr-defined]
        self._last_flush = time.monotonic()

    def close(self) -> None:
        self._writer.close()


def dumps(value: object) -> str:
    return json.dumps(value, indent=1, sort_keys=True)
