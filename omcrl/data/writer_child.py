"""The child process of :class:`omcrl.data.dataset.WriterProcess`: ``python -m omcrl.data.writer_child PARENT_PID``.

It holds the :class:`~omcrl.data.dataset.DatasetWriter`, so that HDF5 failing on a full disk (which could
crash the interpreter) ends this process, not the collector. Protocol on stdin: one JSON line (the writer's
arguments), then per episode a JSON header line followed by its arrays in ``.npy`` format (read with
``allow_pickle=False``), and a closing line; replies are JSON lines on stdout.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from omcrl.data.dataset import DatasetError, DatasetWriter, PipeStream
from omcrl.utils.runtime import exit_with_parent


def main(parent: int) -> int:
    """The body of :class:`WriterProcess`: open the writer, then serve ``add`` and ``close`` until stdin ends."""
    exit_with_parent(parent)
    inp, out = sys.stdin.buffer, sys.stdout.buffer

    def reply(msg: dict) -> None:
        out.write(json.dumps(msg).encode() + b"\n")
        out.flush()

    def fail(e: Exception) -> None:
        reply({"error": "ValueError" if isinstance(e, ValueError) else "DatasetError", "message": str(e)})

    o = json.loads(inp.readline())
    try:
        writer = DatasetWriter(o["path"], o["image_size"], o["frame_stack"], o["env_config"], o["compression"])
    except (DatasetError, ValueError, OSError) as e:
        fail(e)
        return 1
    reply({"n_episodes": writer.n_episodes, "created": writer.created})
    discard = True  # stdin that ends without "close" is a collector that died: as an exception in DatasetWriter
    try:
        while line := inp.readline():
            msg = json.loads(line)
            if msg["op"] == "close":
                discard = bool(msg["discard"])
                break
            arrays = {k: np.lib.format.read_array(PipeStream(inp), allow_pickle=False) for k in msg["fields"]}
            try:
                idx = writer.add_episode(scene=msg["scene"], seed=msg["seed"], source=msg["source"], **arrays)
            except (DatasetError, ValueError) as e:
                fail(e)
            else:
                reply({"index": idx})
    finally:
        writer.close(discard=discard)
        reply({"closed": True})
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2 or not sys.argv[1].isdigit():
        sys.exit("usage: python -m omcrl.data.writer_child PARENT_PID (started by omcrl.data.WriterProcess)")
    sys.exit(main(int(sys.argv[1])))
