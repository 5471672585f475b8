"""A real multi-node Ray cluster runs `htdata ingest --executor ray --address` and writes the process
pool's dataset byte for byte (issue 37).

`ray start --head` and a second node `ray start --address HEAD` are separate processes with separate
temp dirs, started here with `--block` in sessions of their own; the ingest runs as its own
process (the driver), joining the cluster by the head's address. The head offers no CPU to tasks
(as a real cluster's head often does), so every unit runs on the second node and its record comes
back through Ray. Both nodes are stopped in `finally`, by the process ids this test started (the
`ray start` process, its process group, every descendant it had), never by `ray stop` (which would
stop any Ray on the machine), and the test fails if one of them outlives the stop.

Heavier than the rest of the suite (two Ray nodes: ~1 GB, ~30-60 s on 2 cores), so `make test`
leaves it out (marker `cluster`); `make ray-cluster-check` runs it and CI calls that.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import pytest

from tests.factories import ingest_cli, small_pipeline
from tests.factories.executors import make_mixed_sources, same_dataset_bytes

pytestmark = pytest.mark.cluster

START_TIMEOUT_S = 180      # a node's `ray start` on a loaded 2-core machine
INGEST_TIMEOUT_S = 600
STARTED = "Ray runtime started"


def free_ports(n: int) -> list[int]:
    """`n` distinct TCP ports free now on this machine (held open together so none repeats)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind(("", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


# Token authentication with a token of this run: the nodes listen on every interface (Ray binds them
# so), and a token file another Ray left in ~/.ray must not decide whether the nodes may talk.
TOKEN = secrets.token_hex(32)


def ray_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_AUTH_TOKEN_PATH")}
    env.update(RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=TOKEN)
    return env


class RayNode:
    """One `ray start --block` process (a session of its own) and the processes it started."""

    def __init__(self, name: str, args: list[str], temp_dir: Path, log: Path):
        self.name, self.log, self.temp_dir = name, log, temp_dir
        ray = Path(sys.executable).with_name("ray")       # the venv's CLI: ray is a declared dependency
        assert ray.is_file(), f"no ray CLI beside {sys.executable}"
        with open(log, "wb") as out:
            self.proc = subprocess.Popen([str(ray), "start", "--block", f"--temp-dir={temp_dir}", *args],
                                         stdout=out, stderr=subprocess.STDOUT, env=ray_env(), start_new_session=True)
        self.seen: dict[int, psutil.Process] = {}

    def wait_started(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while STARTED not in self.log.read_text(errors="replace"):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"ray node {self.name} did not start (rc {self.proc.poll()}):\n"
                                   f"{self.log.read_text(errors='replace')[-3000:]}")
            time.sleep(0.5)
        self.remember()

    def remember(self) -> None:
        """Note every process of this node (descendants of our `ray start`) so the stop can reach them."""
        with contextlib.suppress(psutil.NoSuchProcess):
            root = psutil.Process(self.proc.pid)
            for p in [root, *root.children(recursive=True)]:
                self.seen.setdefault(p.pid, p)

    def stop(self) -> list[str]:
        """SIGTERM our `ray start` (it stops its node's processes), then SIGKILL whatever of ours is left;
        returns the processes still alive after that (none expected)."""
        self.remember()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                pass
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)       # the session's group: ours alone
        for p in self.seen.values():
            with contextlib.suppress(psutil.NoSuchProcess):
                if p.is_running():
                    p.kill()
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)
        _, alive = psutil.wait_procs([p for p in self.seen.values() if p.pid != self.proc.pid], timeout=30)
        return [f"{self.name}: pid {p.pid}" for p in alive if _running(p)]


def _running(p: psutil.Process) -> bool:
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@contextlib.contextmanager
def local_ray_cluster(cpus: int = 2):
    """A head (no task CPUs) and a second node with `cpus` CPUs; yields the head's address."""
    head_dir, node_dir = (Path(tempfile.mkdtemp(prefix=p, dir="/tmp")) for p in ("htray-h", "htray-n"))  # short:
    # Ray's unix socket paths live under the temp dir and must stay under ~107 characters
    gcs, client, dash, *agents = free_ports(11)
    memory = str(80 * 2**20)
    common = ["--node-ip-address=127.0.0.1", f"--object-store-memory={memory}", "--disable-usage-stats"]
    nodes: list[RayNode] = []
    try:
        head = RayNode("head", ["--head", f"--port={gcs}", "--num-cpus=0", "--include-dashboard=false",
                                f"--dashboard-port={dash}", f"--ray-client-server-port={client}",
                                f"--dashboard-agent-listen-port={agents[0]}", f"--dashboard-agent-grpc-port={agents[1]}",
                                f"--runtime-env-agent-port={agents[2]}", f"--metrics-export-port={agents[3]}",
                                *common], head_dir, head_dir.with_suffix(".log"))
        nodes.append(head)
        head.wait_started()
        address = f"127.0.0.1:{gcs}"
        node = RayNode("node", [f"--address={address}", f"--num-cpus={cpus}",
                                f"--dashboard-agent-listen-port={agents[4]}", f"--dashboard-agent-grpc-port={agents[5]}",
                                f"--runtime-env-agent-port={agents[6]}", f"--metrics-export-port={agents[7]}",
                                *common], node_dir, node_dir.with_suffix(".log"))
        nodes.append(node)
        node.wait_started()
        yield address, [head, node]
    finally:
        leftovers = [p for n in reversed(nodes) for p in n.stop()]
        for d in (head_dir, node_dir):
            shutil.rmtree(d, ignore_errors=True)
            d.with_suffix(".log").unlink(missing_ok=True)
        assert not leftovers, f"Ray processes outlived the stop: {leftovers}"


def test_a_two_node_ray_cluster_writes_the_process_pools_dataset(tmp_path):
    ot, ta = make_mixed_sources(tmp_path / "raw")
    pipes = ["--pipeline", f"{small_pipeline(tmp_path, 'opentouch', 8)}={ot}",
             "--pipeline", f"{small_pipeline(tmp_path, 'touchanything', 8)}={ta}"]
    pool_out, ray_out = tmp_path / "pool", tmp_path / "ray"
    assert ingest_cli(*pipes, pool_out, workers=2) == 0

    with local_ray_cluster() as (address, nodes):
        driver = subprocess.run([sys.executable, "-m", "htdata.cli", "ingest", "--quiet", "--executor", "ray",
                                 "--address", address, *map(str, pipes), str(ray_out)],
                                env=ray_env(), capture_output=True, text=True, timeout=INGEST_TIMEOUT_S)
        assert driver.returncode == 0, driver.stderr[-3000:]
        # the units ran in workers of the second node (the head has no CPU for tasks): their logs are there
        assert list(nodes[1].temp_dir.glob("session_*/logs/python-core-worker-*")), "no worker ran on the node"

    same_dataset_bytes(ray_out, pool_out)
    report = ray_out / "reports" / "ingest.json"
    assert '"failures": []' in report.read_text()

