"""A real two-node Ray cluster on this machine (issue 31, item 6), started as docs/scale_out.md tells:
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
import time
from pathlib import Path

import pytest
from test_compare_run import WALL_CLOCK_COLUMNS
from test_ray_backend import TINY, _rows

from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.store import read_episode_table

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
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


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


def _nodes_alive(address: str, env: dict) -> int:
    code = (f"import ray; ray.init(address={address!r}, logging_level='ERROR'); "
            "print(sum(1 for n in ray.nodes() if n['Alive']))")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    return int(done.stdout.strip().splitlines()[-1]) if done.returncode == 0 and done.stdout.strip() else 0


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


def test_a_two_node_cluster_flies_what_a_local_run_flies(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RAY_USAGE_STATS_ENABLED": "0",
           "PYTHONPATH": os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}
    port = _free_port()
    address = f"127.0.0.1:{port}"
    head = _node(["--head", "--port", str(port), "--node-ip-address", "127.0.0.1", "--include-dashboard=false"],
                 tmp_path / "ray-head", env)
    nodes = [head]
    try:
        deadline = time.monotonic() + 120.0
        while _nodes_alive(address, env) < 1:
            assert head.poll() is None and time.monotonic() < deadline, head.stderr.read() if head.stderr else ""
            time.sleep(1.0)
        nodes.append(_node(["--address", address, "--node-ip-address", "127.0.0.1"], tmp_path / "ray-node", env))
        while _nodes_alive(address, env) < 2:
            assert nodes[1].poll() is None and time.monotonic() < deadline, "the second node did not join"
            time.sleep(1.0)
        common = ["--no-progress", "--videos", "none"]
        cluster = tmp_path / "cluster"
        assert main(["run", str(TINY), "--backend", "ray", "--address", address, "--jobs", "2", "--out",
                     str(cluster), *common]) == 0
    finally:
        for node in reversed(nodes):
            _stop(node)
    local = tmp_path / "local"
    assert main(["run", str(TINY), "--out", str(local), *common]) == 0
    assert _rows(cluster) == _rows(local)
    assert _stored(cluster) == _stored(local)
