"""Rewrite a recorded session in today's format, every message and log time kept as they are:
each chunk with its CRC-32, the settings recorded on ``session/settings``, the planned count of
blocks and how the recording ended. The chunks are closed where the session's own close (its
chunk boundaries hold, which test/bagfaults.py cuts at).

How bags/reference/park1998_fig8 was rewritten (issue 17: its chunks carried CRC 0)::

    .venv/bin/python test/rewrite_reference.py bags/reference/park1998_fig8 /tmp/fig8
    rm -r bags/reference/park1998_fig8 && mv /tmp/fig8 bags/reference/park1998_fig8

(the folder's name is the session's: the .mcap inside is named after it.)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from turning_force.session.bag import CUSTOM_PLANNED, SessionWriter
from turning_force.session.reader import _mcap_file, read_metadata, session_typestore
from turning_force.session.scan import McapScan, scan_mcap


def rewrite(source: Path, out: Path) -> None:
    info, custom, topics = read_metadata(source)
    parameters = json.loads(custom['turning_force.parameters_json'])['experiment']
    planned = round(parameters['duration_s'] / parameters['control_period_s'])
    writer = SessionWriter(out, flush_period_s=float('inf'))
    for key, value in custom.items():
        writer.set_custom_data(key, value)
    writer.set_custom_data(CUSTOM_PLANNED, str(planned))
    added: set[int] = set()

    def chunk(scan: McapScan, data: npt.NDArray[np.uint8], channels: Any, log_times: Any,
              offsets: Any, sizes: Any) -> None:
        for index in sorted(set(channels.tolist()) - added):   # the topics, as recorded
            channel = scan.channels[index]
            schema = scan.schemas[channel.schema_id]
            definition = (schema.name, schema.encoding, schema.data.decode())
            writer.add_topic(channel.topic, schema.name, (
                definition[2], session_typestore((definition,)).hash_rihs01(schema.name)))
            added.add(index)
        for channel, t, o, n in zip(channels.tolist(), log_times.tolist(), offsets.tolist(),
                                    sizes.tolist(), strict=True):
            writer.write(scan.channels[channel].topic, t, bytes(data[o:o + n]))
        writer.flush()   # the chunk closes where the recorder closed it

    # Topics without messages (the first chunk names the others): added after the settings.
    writer.record_settings()
    scan_mcap(_mcap_file(source, info), chunk)
    for name, topic in topics.items():
        if name not in writer.counts:
            writer.add_topic(name, topic.msgtype)
    writer.close()


if __name__ == '__main__':
    rewrite(Path(sys.argv[1]), Path(sys.argv[2]))
