"""A real two-node Ray cluster on this machine, started as docs/scale_out.md tells:
`ray start --head` and a second node joining it with `ray start --address`, each with its own temporary folder
and one CPU. `run --backend ray --address` then flies the tiny scenario on it; metrics.csv and the run store
must be those of a local run (the wall-clock columns aside). The nodes run in their own process groups,
started here and stopped here by those groups (never `ray stop`, which would end every Ray process of the
machine)."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from test_ray_backend import _rows

from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.store import read_episode_table
from run_data import TINY, WALL_CLOCK_COLUMNS

pytest.importorskip("ray")
RAY = shutil.which("ray") or str(Path(sys.executable).with_name("ray"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _node(args: list[str], temp_dir: Path, env: dict) -> subprocess.Popen:
    """`ray start ... --block` in a process group of its own (its raylet and workers join it)."""
    return subprocess.Popen([RAY, "start", *args, "--num-cpus", "1", "--temp-dir", str(temp_dir), "--block",
                             "--disable-usage-stats"], env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _stop(proc: subprocess.Popen) -> None:
    """End a node: its `ray start --block` and everything in its process group (SIGTERM, then SIGKILL)."""
    for sig, wait_s in ((signal.SIGTERM, 15.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            continue
        deadline = time.monotonic() + wait_s  # the group's other processes (raylet, workers) after the leader
        while time.monotonic() < deadline:
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.2)


def _nodes_alive(address: str, env: dict, scratch: Path) -> int:
    """Nodes alive in the cluster at `address` (0: not reachable yet), asked from a process of its own."""
    code = (f"import ray; ray.init(address={address!r}, logging_level='ERROR'); "
            "print(sum(1 for n in ray.nodes() if n['Alive']))")
    out = scratch / "nodes.txt"
    try:  # into a file, not a pipe: a process Ray leaves behind would hold a pipe open, and the wait with it
        with out.open("w") as f:
            done = subprocess.run([sys.executable, "-c", code], env=env, stdout=f, stderr=subprocess.DEVNULL,
                                  timeout=60)
    except subprocess.TimeoutExpired:
        return 0
    text = out.read_text().strip()
    return int(text.splitlines()[-1]) if done.returncode == 0 and text else 0


def _stored(out: Path) -> tuple[list[dict], list[list]]:
    """The episode table without the wall-clock columns and metadata, and each episode's samples without their
    compute times (measured, not simulated)."""
    rows = [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS | {"meta_json"}}
            for r in read_episode_table(out)]
    episodes = open_episodes(out)
    samples = []
    for e in episodes.entries:
        traj = episodes.load(e).trajectory
        samples.append([traj.t_s.tolist(), traj.states.tolist(), traj.rotor_commands.tolist(),
                        traj.clearance_m.tolist(), traj.decision_t_s.tolist()])
    return rows, samples


def test_a_two_node_cluster_flies_what_a_local_run_flies(tmp_path: Path, no_report: None) -> None:
    root = Path(__file__).resolve().parents[3]
    # Ray >= 2.5x turns token authentication on for `ray start`; this private test cluster opts out, so the run
    # (this process) connects as a driver of a cluster without tokens
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled",
           "PYTHONPATH": os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}
    port = _free_port()
    address = f"127.0.0.1:{port}"
    # Ray's sockets live in its temporary folders, whose paths must stay short (AF_UNIX: 107 bytes)
    temp = Path(tempfile.mkdtemp(prefix="uamray-", dir="/tmp"))
    head = _node(["--head", "--port", str(port), "--include-dashboard=false"], temp / "head", env)
    nodes = [head]
    try:
        deadline = time.monotonic() + 120.0
        while _nodes_alive(address, env, temp) < 1:
            assert head.poll() is None and time.monotonic() < deadline, "the head node did not start"
            time.sleep(1.0)
        nodes.append(_node(["--address", address], temp / "node", env))
        while _nodes_alive(address, env, temp) < 2:
            assert nodes[1].poll() is None and time.monotonic() < deadline, "the second node did not join"
            time.sleep(1.0)
        common = ["--no-progress", "--videos", "none"]
        cluster = tmp_path / "cluster"
        # the run is a command of its own, as docs/scale_out.md gives it: in this test process, after the local
        # Ray sessions of earlier tests (test_ray_backend's, with a worker that exits), a cell on the second
        # node was lost to OwnerDiedError 2 of 2 times; a fresh process never was (not reproduced by a
        # minimal script either, so it is kept out of the test's way and named in docs/scale_out.md)
        with (tmp_path / "cluster.log").open("w") as log:  # a file, not a pipe (see _nodes_alive)
            done = subprocess.run([sys.executable, "-m", "compare", "run", str(TINY), "--backend", "ray",
                                   "--address", address, "--jobs", "2", "--out", str(cluster), *common],
                                  env=env, stdout=log, stderr=subprocess.STDOUT, timeout=600)
        assert done.returncode == 0, (tmp_path / "cluster.log").read_text()[-3000:]
    finally:
        for node in reversed(nodes):
            _stop(node)
        shutil.rmtree(temp, ignore_errors=True)
    local = tmp_path / "local"
    assert main(["run", str(TINY), "--out", str(local), *common]) == 0
    assert _rows(cluster) == _rows(local)
    assert repr(_stored(cluster)) == repr(_stored(local))  # NaN (the tracker columns of ppo) equal to NaN
