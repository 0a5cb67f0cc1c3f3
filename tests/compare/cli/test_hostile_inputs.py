"""Hostile inputs, round three: a run folder runs no code, a page runs no script, nothing a user
made is overwritten, vehicles are never pooled by name, and every bad input is one clear line before work.

Cases go through `compare.cli.main` where the command line reaches them and check the exit code, the one
error line (naming the file, key or option and the value), that no traceback escaped and that nothing was
written or changed.
"""
from __future__ import annotations

import json
import re
import shutil
import sys
import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path

import pytest
import yaml

from cli_checks import error_line, fails, snapshot
from compare.cli import main
from compare.results.trajectory import load_episode, save_episode
from run_data import TINY
from scenario_box import BASE  # a 100 x 100 x 50 m box with one building in the middle
from synthetic_run import write_run
from uam_fdm.files.lock import LOCK_NAME

# ---- helpers (as in test_bad_inputs.py) ------------------------------------------------------------------



@pytest.fixture(scope="module")
def base_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("hostile") / "run"
    write_run(out, None)
    return out


@pytest.fixture
def run_copy(base_run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(base_run, out)
    return out


# ---- 1: reading a run folder imports nothing a data file names ----------------------------------------------
EVIL = "import pathlib\npathlib.Path(__file__).with_name('RAN').write_text('imported')\n"


def _rename_pilot(run: Path, pilot: str) -> None:
    """Give one episode file of `run` the pilot `pilot` (as a shared, hostile run folder could)."""
    path = sorted((run / "episodes").glob("*rrt_mpc*.npz"))[0]
    saved = load_episode(path)
    meta = saved.meta
    key = type(meta.key)(meta.key.scenario, meta.key.episode, pilot, meta.key.seed)
    path.unlink()
    save_episode(run / "episodes" / f"{key.stem}.npz", type(meta)(**{**vars(meta), "key": key}), saved.trajectory)


@pytest.mark.parametrize("command", [["report"], ["view"], ["animate", "--format", "gif", "--fps", "2",
                                                            "--duration", "1", "--size", "320x240"]])
def test_reading_a_run_folder_imports_nothing_it_names(run_copy: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture, command: list[str]) -> None:
    (run_copy / "evilpilot_i32.py").write_text(EVIL)  # shipped in the folder, started from inside it
    monkeypatch.chdir(run_copy)
    monkeypatch.syspath_prepend(str(run_copy))
    _rename_pilot(run_copy, "evilpilot_i32:P")
    code = main([command[0], str(run_copy), *command[1:], *(["--no-progress"] if command[0] == "animate" else [])])
    assert code == 0, capsys.readouterr().err
    assert not (run_copy / "RAN").exists()
    assert "evilpilot_i32" not in sys.modules


def test_a_plugin_label_and_colour_come_from_run_json(run_copy: Path) -> None:
    from compare.playback.flights import flight_groups

    _rename_pilot(run_copy, "someone.pilots:Mine")
    info = json.loads((run_copy / "run.json").read_text())
    info["methods"]["someone.pilots:Mine"] = {"label": "Their pilot", "description": "x", "color": "tab:brown"}
    (run_copy / "run.json").write_text(json.dumps(info))
    pilots = {p.pilot: p for g in flight_groups(run_copy) for p in g.flights}
    assert pilots["someone.pilots:Mine"].label == "Their pilot"
    assert pilots["someone.pilots:Mine"].color == "tab:brown"


# ---- 2: nothing from a run folder or scenario becomes script in a page -------------------------------------
ATTACKS = ["</sCrIpT><img src=x onerror=alert(1)>", "</script ><script>alert(1)</script>",
           "<!--<script>", "\u2028\u2029</SCRIPT\t>&lt;", "]]></style><svg onload=alert(1)>"]


def test_the_viewer_embeds_hostile_text_as_data(run_copy: Path, tmp_path: Path) -> None:
    info = json.loads((run_copy / "run.json").read_text())
    info["scenarios"][0]["description"] = ATTACKS[0]
    info["command"] = ATTACKS[1]
    info["methods"]["ppo"]["label"] = ATTACKS[2]
    info["methods"]["rrt_mpc"]["label"] = ATTACKS[3] + ATTACKS[4]
    (run_copy / "run.json").write_text(json.dumps(info))
    out = tmp_path / "v.html"
    assert main(["view", str(run_copy), "--out", str(out)]) == 0
    page = out.read_text(encoding="utf-8")
    # the template's own four scripts (plotly.js, the data, player.js, viewer.js) close, nothing else does; no markup
    # from the data
    assert len(re.findall(r"</script", page, re.IGNORECASE)) == 4
    for markup in ("<img src=x", "<svg onload", "<script>alert", "\u2028"):
        assert markup.lower() not in page.lower()
    data = page.split('<script type="application/json" id="uam-data">')[1].split("</script>")[0]
    assert not re.search("[<>&\u2028\u2029]", data)
    payload = json.loads(data)
    assert payload["run"]["command"] == ATTACKS[1]  # the text itself comes back unchanged
    assert payload["groups"][0]["description"] == ATTACKS[0]
    assert {p["label"] for p in payload["groups"][0]["pilots"]} == {ATTACKS[2], ATTACKS[3] + ATTACKS[4]}


def test_json_for_script_is_safe_for_any_text() -> None:
    from compare.pages.embed import json_for_script

    text = "".join(chr(c) for c in range(0x2100)) + "\u2028\u2029</ScRiPt>"
    out = json_for_script({"t": text})
    assert not re.search(r"[<>&\u2028\u2029]", out)
    assert json.loads(out) == {"t": text}


# ---- 3: train never replaces a policy without being asked ----------------------------------------------------
def test_train_refuses_a_non_empty_out(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "policy"
    out.mkdir()
    (out / "model.zip").write_bytes(b"a policy someone trained for a week")
    fails(["train", "--out", str(out), "--timesteps", "10"], capsys, tmp_path, f"--out {out}", "--overwrite")


@pytest.mark.parametrize(("argv", "expected"), [
    (["--envs", "0"], "--envs 0"), (["--timesteps", "-5"], "--timesteps -5"), (["--eval-every", "0"], "--eval-every 0"),
    (["--eval-episodes", "0"], "--eval-episodes 0"), (["--checkpoint-every", "-1"], "--checkpoint-every -1"),
    (["--envs", "100000000"], "--envs 100000000"), (["--seed", "-1"], "--seed -1"),
    (["--turbulence", "storm"], "--turbulence storm"), (["--vehicle", "zeppelin"], "--vehicle zeppelin"),
    (["--preset", "huge"], "--preset huge"), (["--city-pool", "0"], "--city-pool 0"),
])
def test_train_options_are_named_as_options(tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str],
                                            expected: str) -> None:
    line = fails(["train", "--out", str(tmp_path / "p"), *argv], capsys, tmp_path, expected)
    assert "n_envs" not in line and "total_timesteps" not in line and "eval_every" not in line


def test_evaluate_policy_seed_is_named_as_the_option(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    fails(["evaluate-policy", "--seed", "-1", "--episodes", "1"], capsys, tmp_path, "--seed -1")


# ---- 4: two vehicles that share a name are two vehicles -------------------------------------------------------
def test_vehicles_sharing_a_name_are_never_pooled(run_copy: Path, capsys: pytest.CaptureFixture) -> None:
    """Episode 1 is re-filed as a second scenario flying a heavier copy of the preset that kept its name."""
    info = json.loads((run_copy / "run.json").read_text())
    info["scenarios"].append({**info["scenarios"][0], "name": "heavy"})
    (run_copy / "run.json").write_text(json.dumps(info))
    shutil.copy(run_copy / "maps" / f"{info['scenarios'][0]['name']}.yaml", run_copy / "maps" / "heavy.yaml")
    for path in sorted((run_copy / "episodes").glob("*.npz")):
        saved = load_episode(path)
        meta, heavy = saved.meta, saved.meta.key.episode == 1
        key = type(meta.key)("heavy", 0, meta.key.method, 0) if heavy else meta.key
        path.unlink()
        save_episode(run_copy / "episodes" / f"{key.stem}.npz",
                     type(meta)(**{**vars(meta), "key": key, "vehicle_fingerprint": ("b" if heavy else "a") * 64}),
                     saved.trajectory)
    assert main(["report", str(run_copy)]) == 0
    summary = json.loads((run_copy / "summary.json").read_text())
    assert sorted(summary["vehicles"]) == ["small_quad (aaaaaaaa)", "small_quad (bbbbbbbb)"]
    text = (run_copy / "metrics.csv").read_text()
    assert "small_quad (aaaaaaaa)" in text and "b" * 64 in text
    out = capsys.readouterr().out
    assert "small_quad (aaaaaaaa)" in out and "small_quad (bbbbbbbb)" in out


# ---- 5: the flight volume is bounded before anything is sized by it ------------------------------------------
def _scenario(tmp_path: Path, data: dict, name: str = "scen.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.parametrize(("lo", "hi", "expected"), [
    ([0, 0, 0], [100, 100, 1e8], "bounds.max: ceiling z 1e+08 m"),
    ([0, 0, 0], [100, 100, 1e13], "bounds.max: ceiling z 1e+13 m"),
    ([0, 0, 0], [1e7, 100, 50], "bounds: x beyond"),
    ([-3e4, 0, 0], [100, 100, 50], "wide in x"),
    ([0, 0, 0], [100, 2e5, 50], "200000 m wide in y"),
])
def test_a_huge_flight_volume_is_refused_at_once(tmp_path: Path, capsys: pytest.CaptureFixture, lo: list,
                                                 hi: list, expected: str) -> None:
    path = _scenario(tmp_path, {**BASE, "bounds": {"min": lo, "max": hi}})
    fails(["validate", str(path)], capsys, tmp_path, str(path), expected)


# ---- 6: numbers too large to be numbers ----------------------------------------------------------------------
HUGE = "1" + "0" * 400


@pytest.mark.parametrize("where", ["height", "seeds", "episodes", "timeout"])
def test_a_huge_integer_in_a_scenario_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture, where: str) -> None:
    text = yaml.safe_dump({**BASE, "timeout_s": 60}, sort_keys=False)
    text = {"height": text.replace("height: 30.0", f"height: {HUGE}"),
            "seeds": text + f"seeds: [{HUGE}]\n",
            "episodes": yaml.safe_dump({**BASE, "episodes": [{"start": [10.0, 50.0, 10.0],
                                                                 "goal": [123456.789, 50.0, 10.0]}]},
                                       sort_keys=False).replace("123456.789", HUGE),
            "timeout": text.replace("timeout_s: 60", f"timeout_s: {HUGE}")}[where]
    path = tmp_path / "scen.yaml"
    path.write_text(text)
    fails(["validate", str(path)], capsys, tmp_path, str(path), "401 digits")


def test_a_huge_integer_in_a_geojson_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ring = [[100, 100], [200, 100], [200, 200], [100, 200], [100, 100]]
    feature = {"type": "Feature", "properties": {"height": 123456.789},
               "geometry": {"type": "Polygon", "coordinates": [ring]}}
    doc = json.dumps({"type": "FeatureCollection", "features": [feature]}).replace("123456.789", HUGE)
    (tmp_path / "fp.geojson").write_text(doc)
    path = _scenario(tmp_path, {**BASE, "map": {"geojson": "fp.geojson"},
                                "bounds": {"min": [0, 0, 0], "max": [300, 300, 100]},
                                "episodes": [{"start": [10.0, 10.0, 10.0], "goal": [290.0, 20.0, 10.0]}]})
    fails(["validate", str(path)], capsys, tmp_path, "fp.geojson", "401 digits")


# ---- 6: a plug-in is checked whole before anything flies -------------------------------------------------------
PLUGIN_PILOT = '''
from rl.pilots.potential_field import PotentialFieldPilot
class P(PotentialFieldPilot):
    """A plug-in pilot."""
'''


@pytest.mark.parametrize(("source", "expected"), [
    ("raise RuntimeError('boom at import')", "failed: RuntimeError: boom at import"),
    ("def broken(:\n    pass", "syntax error in"),
    ("import sys\nsys.exit(3)", "it called sys.exit(3)"),
    ("raise KeyError('x')", "failed: KeyError"),
    (PLUGIN_PILOT + "    def __init__(self, gain):\n        super().__init__()", "needs the argument(s) gain"),
    (PLUGIN_PILOT + "    color = 'not-a-colour'", "color 'not-a-colour' is not a matplotlib colour"),
    (PLUGIN_PILOT + "    label = 'costs $5 per $km'", "holds '$'"),
    (PLUGIN_PILOT + "    description = 'a $\\\\frac{1}{0$ pilot'", "holds '$'"),
    (PLUGIN_PILOT + "    label = 'x' * 5000", "5000 characters long"),
])
def test_a_broken_plugin_is_one_line_before_flying(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture, source: str, expected: str) -> None:
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    module = f"plug_i32_{abs(hash(source)) % 10**8}"
    (plugins / f"{module}.py").write_text(source + "\n")
    monkeypatch.syspath_prepend(str(plugins))
    path = _scenario(tmp_path, {**BASE, "pilots": ["apf", f"{module}:P"]})
    fails(["validate", str(path)], capsys, tmp_path, f"{module}:P", expected)
    fails(["run", str(TINY), "--pilot", f"{module}:P", "--out", str(tmp_path / "run")], capsys, tmp_path,
           "--pilot", expected)


# ---- 6: names the readers would hide or that break the pages ----------------------------------------------------
def test_a_scenario_name_starting_with_a_dot_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = _scenario(tmp_path, {**BASE, "name": ".hidden"})
    fails(["validate", str(path)], capsys, tmp_path, str(path), "name", "not start with '.'")


def test_an_absurdly_long_vehicle_name_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from uam_fdm.vehicle.params import PRESET_DIR

    text = (PRESET_DIR / "small_quad.yaml").read_text()
    vehicle = tmp_path / "v.yaml"
    vehicle.write_text(re.sub(r"(?m)^name: .*$", "name: " + "q" * 5000, text))
    path = _scenario(tmp_path, {**BASE, "vehicle": "v.yaml"})
    fails(["validate", str(path)], capsys, tmp_path, "v.yaml", "name", "got 5000")


def test_dollars_in_a_description_do_not_break_the_report(run_copy: Path) -> None:
    info = json.loads((run_copy / "run.json").read_text())
    info["scenarios"][0]["description"] = "a $\\frac{1}{0$ district, $$ and $"
    info["methods"]["rrt_mpc"]["label"] = "RRT$^*$ + $MPC"
    (run_copy / "run.json").write_text(json.dumps(info))
    assert main(["report", str(run_copy)]) == 0


# ---- 6: the last resort -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("raised", [RuntimeError("an internal bug"), SystemExit(4), RecursionError("deep")])
def test_an_internal_error_is_one_line_with_the_traceback_logged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                capsys: pytest.CaptureFixture,
                                                                raised: BaseException) -> None:
    import compare.cli.entry
    import compare.cli.validate

    def broken(*_args: object) -> None:
        raise raised

    monkeypatch.setenv(compare.cli.entry.LOG_DIR_ENV, str(tmp_path / "logs"))
    monkeypatch.setattr(compare.cli.validate, "resolve_scenarios", broken)
    line = fails(["validate", str(TINY)], capsys, tmp_path / "nothing", "validate: internal error",
                  type(raised).__name__, code=1)
    logged = Path(line.split("full traceback in ")[1])
    assert logged.parent == tmp_path / "logs" and "Traceback" in logged.read_text()


def test_an_error_names_the_file_not_its_temporary(tmp_path: Path) -> None:
    import errno

    from compare.cli.entry import os_error_message

    exc = OSError(errno.ENOSPC, "No space left on device", str(tmp_path / ".metrics.csv.partial-k2j4.tmp"))
    text = os_error_message(exc)
    assert ".partial-" not in text and str(tmp_path / "metrics.csv") in text and "disk is full" in text


# ---- 7: a pilot's unflyable command is a pilot error, not a collision ------------------------------------------
NAN_PILOTS = '''
import numpy as np
from uam_fdm.pilot import RotorCommand, VelocityCommand
from rl.pilots.potential_field import PotentialFieldPilot

class NaNRotors(PotentialFieldPilot):
    def act(self, obs):
        return RotorCommand(np.full(4, np.nan))

class ShortVelocity(PotentialFieldPilot):
    def act(self, obs):
        return VelocityCommand(np.array([1.0, 2.0]))

class InfVelocity(PotentialFieldPilot):
    def act(self, obs):
        return VelocityCommand(np.array([1.0, np.inf, 0.0]))
'''


def test_an_unflyable_command_fails_the_cell_as_a_pilot_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture, no_report: None) -> None:
    (tmp_path / "nan_pilots_i32.py").write_text(NAN_PILOTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "run"
    plugins = ["nan_pilots_i32:NaNRotors", "nan_pilots_i32:ShortVelocity", "nan_pilots_i32:InfVelocity"]
    argv = ["run", str(TINY), "--pilots", ",".join(["apf", *plugins]), "--out", str(out), "--no-progress",
            "--videos", "none"]
    for m in ["apf", *plugins]:
        argv += ["--pilot", m]
    assert main(argv) == 0, capsys.readouterr().err
    records = {json.loads(p.read_text())["key"]["method"]: json.loads(p.read_text())
               for p in (out / "failed").glob("*.json")}
    assert set(records) == set(plugins)
    for m, expected in zip(plugins, ["[nan nan nan nan]: not finite", "of shape (2,)", "not finite"]):
        assert records[m]["kind"] == "pilot error"
        assert f"pilot '{m}'" in records[m]["reason"] and expected in records[m]["reason"], records[m]["reason"]
    rows = (out / "metrics.csv").read_text().splitlines()[1:]
    assert [r.split(",")[2] for r in rows] == ["apf"]  # no episode, so no collision scored, for the three


# ---- 6: nothing a user made is replaced without being asked ------------------------------------------------------
@pytest.mark.parametrize("command", [["view"], ["animate", "--format", "gif"]])
def test_view_and_animate_never_replace_a_named_file(run_copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                     command: list[str]) -> None:
    mine = run_copy / "metrics.csv" if command[0] == "view" else tmp_path / "holiday.gif"
    mine.write_text("my own file")
    fails([command[0], str(run_copy), "--out", str(mine), *command[1:]], capsys, tmp_path, f"--out {mine}",
           "--overwrite")


# ---- 6: resources: the readers never block, inflate or stop on one file ------------------------------------------
def test_a_fifo_named_like_an_episode_is_not_read(run_copy: Path, capsys: pytest.CaptureFixture) -> None:
    import os

    fifo = run_copy / "episodes" / "toy-quad__ep009__ppo__s0.npz"
    os.mkfifo(fifo)
    # A writer waits for a reader: if the report opened the FIFO, the writer is let through (and closes at once,
    # so the reader sees an empty file instead of blocking); if not, the test itself lets it through afterwards.
    readers: list[str] = []

    def writer() -> None:
        with open(fifo, "wb"):
            readers.append("report" if not done else "test")

    done = False
    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    assert main(["report", str(run_copy)]) == 0, capsys.readouterr().err
    done = True
    os.close(os.open(fifo, os.O_RDONLY | os.O_NONBLOCK))  # the test's own reader: releases the writer
    thread.join()
    assert readers == ["test"], "the report opened the FIFO"


def test_an_episode_that_inflates_hugely_is_refused_unread(run_copy: Path, monkeypatch: pytest.MonkeyPatch,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    import zipfile

    import compare.results.trajectory

    monkeypatch.setattr(compare.results.trajectory, "MAX_EPISODE_BYTES", 2**23)  # the same check, 128 times smaller
    path = sorted((run_copy / "episodes").glob("*.npz"))[0]
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as z:  # a few kB on disk, 16 MiB inflated
        z.writestr("padding.npy", bytes(2**24))
    assert main(["report", str(run_copy)]) == 0
    assert path.name in caplog.text and "MiB in memory" in caplog.text


def test_one_nan_episode_is_skipped_by_name(run_copy: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = sorted((run_copy / "episodes").glob("*.npz"))[0]
    saved = load_episode(path)
    traj = saved.trajectory
    t = traj.t_s.copy()
    t[5] = float("nan")
    save_episode(path, saved.meta, type(traj)(**{**vars(traj), "t_s": t}))
    assert main(["report", str(run_copy)]) == 0
    assert path.name in caplog.text and "t_s" in caplog.text


def test_jobs_far_above_the_cells_start_one_worker_per_cell(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import compare.run.campaign

    seen: list[int] = []

    def open_backend(name: str, setup: object, jobs: int, *args: object, **kwargs: object) -> object:
        seen.append(jobs)
        raise ValueError("stop here")

    monkeypatch.setattr(compare.run.campaign, "open_backend", open_backend)
    assert main(["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--jobs", "64",
                 "--out", str(tmp_path / "run"), "--videos", "none"]) == 2
    assert seen == [1]


# ---- a run folder is written by one command at a time -------------------------------------------------------
FLY_APF = ["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--videos", "none", "--no-progress"]

def test_report_refuses_a_folder_a_run_is_writing(run_copy: Path, capsys: pytest.CaptureFixture) -> None:
    from uam_fdm.files.lock import folder_lock

    with folder_lock(run_copy, "uam-compare run tiny.yaml"):  # as a run flying into it holds it
        line = fails(["report", str(run_copy)], capsys, run_copy, str(run_copy), "another uam-compare process",
                      "uam-compare run tiny.yaml")
    assert str(__import__("os").getpid()) in line
    assert main(["report", str(run_copy)]) == 0  # once the writer has finished
    assert not any(p.name.endswith(".lock") for p in run_copy.iterdir())


def test_a_run_into_a_folder_another_run_holds_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Two runs started together into one --out: the second stops under the lock, writing nothing."""
    from uam_fdm.files.lock import folder_lock

    out = tmp_path / "run"
    with folder_lock(out, "uam-compare run other.yaml"):
        fails([*FLY_APF, "--out", str(out)], capsys, tmp_path, "another uam-compare process", "other.yaml")


def test_a_run_finding_files_under_the_lock_refuses_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    """The folder was empty when the command started and is not when it takes the lock: nothing is replaced."""
    import compare.run.campaign
    from uam_fdm.files.lock import folder_lock

    out = tmp_path / "run"
    real = folder_lock

    def late(folder: Path, command: str):  # another run wrote its run.json between our check and our lock
        (Path(folder) / "run.json").parent.mkdir(parents=True, exist_ok=True)
        (Path(folder) / "run.json").write_text("{}")
        return real(folder, command)

    monkeypatch.setattr(compare.run.campaign, "folder_lock", late)
    assert main([*FLY_APF, "--out", str(out)]) == 2
    assert "folder exists and is not empty" in error_line(capsys.readouterr().err)
    assert [p.name for p in out.iterdir()] == ["run.json"] and (out / "run.json").read_text() == "{}"


def test_a_killed_holder_leaves_no_lock_behind(tmp_path: Path) -> None:
    import subprocess

    from uam_fdm.files.lock import LOCK_NAME, folder_lock

    code = ("import os, sys; from uam_fdm.files.lock import folder_lock\n"
            "with folder_lock(sys.argv[1], 'x'):\n    os._exit(9)\n")  # dies holding it, no cleanup
    assert subprocess.run([sys.executable, "-c", code, str(tmp_path)]).returncode == 9
    assert (tmp_path / LOCK_NAME).exists()  # the file stays, the lock died with its process
    with folder_lock(tmp_path, "uam-compare report"):
        pass


# ---- a run folder's data never chooses a path; a lock never follows a link ---------------------------------------
@pytest.fixture(scope="module")
def flown_run(tmp_path_factory: pytest.TempPathFactory,
              scoring_only: Callable[[], AbstractContextManager[None]]) -> Path:
    """A real run of the tiny scenario by the potential field (quick), its episodes in the run store (scored, no
    report or viewer)."""
    out = tmp_path_factory.mktemp("flown") / "run"
    with scoring_only():
        assert main([*FLY_APF, "--out", str(out)]) == 0
    assert (out / "store" / "episodes.parquet").exists()
    return out


@pytest.fixture
def flown_copy(flown_run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "shared" / "run"
    shutil.copytree(flown_run, out)
    return out


def _rewrite_episode_table(run: Path, column: str, value: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = run / "store" / "episodes.parquet"
    table = pq.read_table(path)
    i = table.schema.get_field_index(column)
    table = table.set_column(i, table.schema.field(i), pa.array([value] * table.num_rows, pa.string()))
    pq.write_table(table, path)


@pytest.mark.parametrize("command", [["report"], ["run", "--resume"]])
def test_a_lock_never_follows_a_link_planted_in_the_folder(flown_copy: Path, capsys: pytest.CaptureFixture,
                                                           command: list[str]) -> None:
    """`ln -s ~/notes.txt RUN/.uam-compare.lock; uam-compare report RUN`: refused, naming the lock; the file the
    link points to and the link itself are left as they were."""
    notes = flown_copy.parent / "notes.txt"
    notes.write_text("my notes")
    (flown_copy / LOCK_NAME).symlink_to(notes)
    argv = ["report", str(flown_copy)] if command == ["report"] else [*FLY_APF, "--out", str(flown_copy), "--resume"]
    fails(argv, capsys, flown_copy.parent, str(flown_copy / LOCK_NAME), "symbolic link")
    assert notes.read_text() == "my notes" and (flown_copy / LOCK_NAME).is_symlink()


def test_a_fifo_in_place_of_the_lock_is_refused(flown_copy: Path, capsys: pytest.CaptureFixture) -> None:
    import os

    os.mkfifo(flown_copy / LOCK_NAME)
    before = (flown_copy / "metrics.csv").read_bytes()
    assert main(["report", str(flown_copy)]) == 2  # (the folder is not hashed: reading the FIFO would block)
    line = error_line(capsys.readouterr().err)
    assert str(flown_copy / LOCK_NAME) in line and "not a regular file" in line
    assert (flown_copy / "metrics.csv").read_bytes() == before and (flown_copy / LOCK_NAME).is_fifo()


@pytest.mark.parametrize("command", [["animate", "--all", "--format", "gif", "--fps", "2", "--duration", "1",
                                      "--size", "320x240", "--no-progress"], ["view"], ["report"]])
def test_a_scenario_name_in_the_store_never_chooses_where_files_go(flown_copy: Path, capsys: pytest.CaptureFixture,
                                                                   command: list[str]) -> None:
    """The store's scenario column reads `zz/../../../ESCAPED`: no reader writes or opens anything outside the
    run folder because of it; every row is skipped by name."""
    _rewrite_episode_table(flown_copy, "scenario", "zz/../../../ESCAPED")
    outside = snapshot(flown_copy.parent.parent)
    code = main([command[0], str(flown_copy), *command[1:]])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    assert "Traceback" not in err and "episodes.parquet" in err, err  # the rows skipped, the table named
    after = snapshot(flown_copy.parent.parent)
    assert {k for k in after if "ESCAPED" in k} == set()
    assert {k for k in set(after) ^ set(outside) if not k.startswith("shared/run/")} == set()


def test_a_samples_file_outside_the_store_is_never_read(flown_copy: Path, capsys: pytest.CaptureFixture,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """`samples_file = ../../victim/store/...`: the rows are skipped by name; no file outside the run is read."""
    victim = flown_copy.parent / "victim"
    shutil.copytree(flown_copy, victim)
    name = next((flown_copy / "store").glob("samples-*.parquet")).name
    _rewrite_episode_table(flown_copy, "samples_file", f"../../victim/store/{name}")
    import pyarrow.parquet as pq

    opened: list[str] = []
    real_open = pq.ParquetFile

    def spy(source, *args, **kwargs):
        opened.append(str(source))
        return real_open(source, *args, **kwargs)
    monkeypatch.setattr("pyarrow.parquet.ParquetFile", spy)
    assert main(["report", str(flown_copy)]) in (0, 2)
    err = capsys.readouterr().err
    assert "samples_file" in err and "episodes.parquet" in err, err
    assert not [p for p in opened if "victim" in p]
