"""Write a fresh recording of the reference session in the reference's layout: every message, log
time and custom datum kept, the first chunk closed after the servo/currents block that ends at 5.93
s and its answers (FIRST_CHUNK_BLOCKS, test/bagfaults.py), the rest in the second, so that the
session-fault tests cut it where they always have. A recording's own chunks close on the wall clock
(SessionWriter's flush_period_s), which no two runs share.

How bags/reference/park1998_fig8 was re-recorded when the controller's behaviour changed on
purpose (the anti-windup on the override applied, issue 16)::

    mkdir -p /tmp/ref && .venv/bin/turning-force run config/experiments/park1998_fig8.yaml \\
        --out /tmp/ref/park1998_fig8
    .venv/bin/python test/relayout_reference.py /tmp/ref/park1998_fig8 /tmp/fig8
    rm -r bags/reference/park1998_fig8 && mv /tmp/fig8 bags/reference/park1998_fig8
    cp /tmp/ref/park1998_fig8.png bags/reference/
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bagfaults import FIRST_CHUNK_BLOCKS
from turning_force.nodes.session_recorder import LATCHED_TOPICS
from turning_force.session.bag import SessionWriter
from turning_force.session.reader import _mcap_file, read_metadata, session_typestore
from turning_force.session.scan import McapScan, scan_mcap


def relayout(source: Path, out: Path) -> None:
    info, custom, topics = read_metadata(source)
    writer = SessionWriter(out, flush_period_s=float('inf'))
    for key, value in custom.items():
        writer.set_custom_data(key, value)
    added: set[int] = set()
    blocks = 0

    def chunk(scan: McapScan, data: npt.NDArray[np.uint8], channels: Any, log_times: Any,
              offsets: Any, sizes: Any) -> None:
        nonlocal blocks
        for index in sorted(set(channels.tolist()) - added):   # the topics, as recorded
            channel = scan.channels[index]
            schema = scan.schemas[channel.schema_id]
            definition = (schema.name, schema.encoding, schema.data.decode())
            writer.add_topic(channel.topic, schema.name, (
                definition[2], session_typestore((definition,)).hash_rihs01(schema.name)),
                latched=channel.topic.lstrip('/') in LATCHED_TOPICS)
            added.add(index)
        for channel, t, o, n in zip(channels.tolist(), log_times.tolist(), offsets.tolist(),
                                    sizes.tolist(), strict=True):
            topic = scan.channels[channel].topic
            if topic.endswith('servo/currents'):
                blocks += 1
                if blocks == FIRST_CHUNK_BLOCKS + 1:   # the first's answers in with it
                    writer.flush()
            writer.write(topic, t, bytes(data[o:o + n]))

    scan_mcap(_mcap_file(source, info), chunk)
    for name, topic in topics.items():
        if name not in writer.counts:
            writer.add_topic(name, topic.msgtype)
    writer.close()


if __name__ == '__main__':
    relayout(Path(sys.argv[1]), Path(sys.argv[2]))
