"""`htdata view --web`: a client connects to the served data port and reads the maps back.

The page (web port) is Rerun's; what must be true of ours is that the gRPC server it reads stays up
while the command serves, and streams the episode's maps as `--save` writes them. The client is
Rerun's own CLI (`rerun URL --save FILE.rrd`), a separate process, as a browser would be.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from htdata.inspect import view
from tests.factories import MIXED_HANDS_EPISODES, mixed_hands_coverages, write_synthetic_dataset

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("rerun") is None,
                       reason="rerun-sdk is not installed (pip install '.[view]')"),
    pytest.mark.filterwarnings("ignore:RRD file has no footer"),   # the client's file is read while written
]
BIN = Path(sys.executable).parent
MAP = "/tactile/left/map"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def map_buffers(path: Path) -> dict[int, bytes]:
    """{frame: the left map's buffer bytes} of an .rrd, read with Rerun's own reader (a partial
    stream file, still being written, reads up to its last whole chunk)."""
    from rerun.chunk import RrdReader

    out = {}
    try:
        chunks = list(RrdReader(path).stream().to_chunks())
    except Exception:   # noqa: BLE001 - the client has not flushed a whole chunk yet
        return out
    for chunk in chunks:
        if chunk.entity_path != MAP or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        frames = batch.column("frame").to_numpy()
        buf = [n for n in batch.schema.names if n.endswith("buffer")][0]
        for k in range(batch.num_rows):
            out[int(frames[k])] = np.asarray(batch.column(buf)[k].values[0].values, np.uint8).tobytes()
    return out


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_the_served_stream_holds_the_episode_maps_while_the_command_serves(tmp_path):
    ds = write_synthetic_dataset(tmp_path / "ds", MIXED_HANDS_EPISODES, coverages=mixed_hands_coverages())
    saved = tmp_path / "saved.rrd"
    view.view_episode(ds, episode="ep_b", save=saved, contrast="fixed")
    want = map_buffers(saved)
    assert len(want) == 4

    web_port, grpc_port = free_port(), free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    server = subprocess.Popen([str(BIN / "htdata"), "view", str(ds), "--episode", "ep_b", "--contrast", "fixed",
                               "--web", "--no-browser", "--web-port", str(web_port), "--grpc-port", str(grpc_port)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    client = None
    got: dict[int, bytes] = {}
    try:
        line = server.stdout.readline()
        assert line.startswith("serving ep_b") and f":{grpc_port}/proxy" in line, \
            (line, server.stderr.read() if server.poll() is not None else "")
        time.sleep(1.0)   # the command is now waiting: the data port must still be served
        assert server.poll() is None
        streamed = tmp_path / "streamed.rrd"
        client = subprocess.Popen([str(BIN / "rerun"), f"rerun+http://127.0.0.1:{grpc_port}/proxy",
                                   "--save", str(streamed), "--port", str(free_port())],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(got) < len(want):
            time.sleep(0.5)
            if streamed.is_file():
                got = map_buffers(streamed)
    finally:
        if client is not None:
            stop(client)
        stop(server)
    assert got == want, f"served frames {sorted(got)} vs saved {sorted(want)}"
