"""How quickly the CLI refuses bad input, builds a report and stops when interrupted.

The tests prove what these commands do (one error line, exit 2, nothing written; the report's pages; a run that
stops with its workers and says what it kept); this script measures how long each takes, which no test asserts.

* Inputs: each input of the tests' catalogue that once hung or was slow (an alias bomb, a generated city too
  large, a 600-vertex star footprint (valid), a self-crossing footprint of one vertex over the limit, a motor
  too fast for the physics rate, a flight volume of 1e13 m, the maps written over a file), through
  `compare.cli.main` in this process, against the baseline of validating the smallest valid scenario in the
  same run. Median of `--repeats`.
* The star footprint's decomposition at 600 and 4,000 vertices (near-linear: the time ratio against the
  vertex ratio, 6.7).
* The report of the tests' synthetic run folder (`tests/synthetic_run.py`, every page kind) against the report
  of the same folder without a policy's training pages.
* A parallel run of the tiny scenario (2 workers, the learned pilot) interrupted with Ctrl-C once an episode is
  saved: seconds from the signal to the command's exit (`--no-interrupt` skips it).

    OMP_NUM_THREADS=1 python perf/responsiveness.py [--repeats 5] [--no-interrupt]

Prints a table and, as its last line, one JSON object of the figures.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the synthetic run folder and the smallest valid scenario
sys.path.insert(0, str(ROOT))  # the packages before tests/'s mirrored folders

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from compare.cli import main as cli_main  # noqa: E402
from compare.report.report import build_report  # noqa: E402
from compare.results.store import part_files  # noqa: E402
from scenario_box import BASE  # noqa: E402
from slow_inputs import alias_bomb, geojson_scenario, star  # noqa: E402
from synthetic_run import write_run  # noqa: E402
from uam_fdm.city.geojson import MAX_FOOTPRINT_VERTICES, footprint_parts  # noqa: E402
from uam_fdm.vehicle.params import PRESET_DIR  # noqa: E402

TINY = ROOT / "tests" / "data" / "tiny_scenario.yaml"
QUAD_YAML = (PRESET_DIR / "small_quad.yaml").read_text()
def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path

def _cases(folder: Path) -> dict[str, tuple[list[str], int]]:
    """Name -> (argv, expected exit code)."""
    box = {k: v for k, v in BASE.items() if k != "bounds"}
    ang = np.linspace(0.0, 2.0 * np.pi, MAX_FOOTPRINT_VERTICES + 1, endpoint=False)  # one vertex too many
    crossing = np.column_stack([150 + 60 * np.cos(ang), 150 + 60 * np.sin(ang)])
    crossing[[1, 2]] = crossing[[2, 1]]  # and self-crossing: refused for its size before any other check
    (folder / "crossing").mkdir()
    (folder / "star").mkdir()
    return {
        "valid scenario (baseline)": (["validate", str(_write(folder, "ok.yaml", yaml.safe_dump(BASE)))], 0),
        "alias bomb": (["validate", str(_write(folder, "bomb.yaml", yaml.safe_dump(BASE, sort_keys=False)
                                               + "extra:\n" + alias_bomb(7)))], 2),
        "city too large": (["validate", str(_write(folder, "city.yaml", yaml.safe_dump(
            {**box, "map": {"generator": {"seed": 1, "extent_m": [6000, 6000]}}})))], 2),
        "600-vertex star": (["validate", str(geojson_scenario(folder / "star", star(600)))], 0),
        "footprint over the vertex limit": (["validate", str(geojson_scenario(folder / "crossing", crossing))], 2),
        "motor too fast": (["demo", str(_write(folder, "vehicle.yaml", QUAD_YAML.replace(
            "motor_time_constant_s: 0.0125", "motor_time_constant_s: 0.0005")))], 2),
        "flight volume 1e13 m": (["validate", str(_write(folder, "huge.yaml", yaml.safe_dump(
            {**BASE, "bounds": {"min": [0, 0, 0], "max": [100, 100, 1e13]}})))], 2),
        "maps over a file": (["maps", str(_write(folder, "maps.png", "keep me"))], 2),
    }


def _median_s(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _quiet_cli(argv: list[str], code: int) -> None:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        got = cli_main(argv)
    if got != code:
        raise SystemExit(f"{' '.join(argv)}: exit {got}, expected {code}")


def input_times(folder: Path, repeats: int) -> dict[str, float]:
    """Median seconds of each case, the baseline first."""
    out = {}
    for name, (argv, code) in _cases(folder).items():
        _quiet_cli(argv, code)  # warm: imports and caches, as in a session
        out[name] = _median_s(lambda a=argv, c=code: _quiet_cli(a, c), repeats)
    return out


def report_seconds(folder: Path) -> tuple[float, float]:
    """Seconds of the synthetic run's whole report, and of the same run without the policy's pages."""
    full, small = folder / "full", folder / "small"
    write_run(full / "run", full / "policy")
    write_run(small / "run", None)
    build_report(small / "run")  # warm: matplotlib's fonts and caches
    t0 = time.perf_counter()
    build_report(full / "run")
    full_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    build_report(small / "run")
    return full_s, time.perf_counter() - t0


def interrupt_seconds(folder: Path) -> float:
    """Seconds from Ctrl-C (SIGINT to the process group) to the exit of a 2-worker run, once an episode is saved."""
    out = folder / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "compare", "run", str(TINY), "--pilots", "ppo", "--seeds", "0,1,2,3", "--jobs", "2",
         "--out", str(out), "--no-progress", "--videos", "none"], cwd=ROOT,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        while not part_files(out) and proc.poll() is None:
            time.sleep(0.02)
        if proc.poll() is not None:
            raise SystemExit("the run ended before an episode was saved")
        os.killpg(proc.pid, signal.SIGINT)
        t0 = time.perf_counter()
        proc.wait(timeout=300)
        return time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timings per input (median)")
    parser.add_argument("--no-interrupt", action="store_true", help="skip the interrupted run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name in ("inputs", "report", "interrupt"):
            (root / name).mkdir()
        times = input_times(root / "inputs", args.repeats)
        star_s = {n: _median_s(lambda n=n: footprint_parts(star(n), 20.0, 0), args.repeats) for n in (600, 4000)}
        report_s, report_small_s = report_seconds(root / "report")
        stop_s = None if args.no_interrupt else interrupt_seconds(root / "interrupt")

    base = times["valid scenario (baseline)"]
    print(f"{'input':<34}{'median [ms]':>12}{'x baseline':>12}")
    for name, s in times.items():
        print(f"{name:<34}{1e3 * s:>12.1f}{s / base:>12.2f}")
    scaling = star_s[4000] / star_s[600]
    print(f"\nstar footprint decomposition: 600 vertices {1e3 * star_s[600]:.1f} ms, 4,000 vertices "
          f"{1e3 * star_s[4000]:.1f} ms: x{scaling:.1f} for x{4000 / 600:.1f} the vertices")
    print(f"report of the synthetic run: {report_s:.1f} s; without the policy's pages {report_small_s:.1f} s "
          f"(x{report_s / report_small_s:.2f})")
    if stop_s is not None:
        print(f"interrupted 2-worker run: exit {stop_s:.2f} s after Ctrl-C")
    cases = {k: v for k, v in times.items() if k != "valid scenario (baseline)"}
    print(json.dumps({
        "input_ms": {k: round(1e3 * v, 2) for k, v in cases.items()},
        "valid_ms": round(1e3 * base, 2),
        "input_ms_max": round(1e3 * max(cases.values()), 2),
        "input_ratio_max": round(max(cases.values()) / base, 2),
        "star_600_ms": round(1e3 * star_s[600], 2), "star_4000_ms": round(1e3 * star_s[4000], 2),
        "star_time_ratio": round(scaling, 2), "star_vertex_ratio": round(4000 / 600, 2),
        "report_s": round(report_s, 2), "report_small_s": round(report_small_s, 2),
        "report_ratio": round(report_s / report_small_s, 2),
        "interrupt_stop_s": None if stop_s is None else round(stop_s, 2),
    }))


if __name__ == "__main__":
    main()
