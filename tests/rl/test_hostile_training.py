"""Hostile inputs to training and to what training writes: resuming from a folder that cannot be resumed, a
policy whose numbers overflow, non-finite numbers and deep nesting in the JSON of policy and run folders,
provenance that names the machine a shipped policy was trained on, training flights that inflate far beyond their
file's size or are longer than a page draws, and a link planted in a policy folder.

Each bad input is one clear line (naming the folder or file, the key and the value), exit code 2, before
anything is built or written; nothing here trains (a resume that got past its checks would meet a stand-in that
fails the test at once).
"""
from __future__ import annotations

import json
import re
import shutil
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

import rl.training.loop
from cli_checks import error_line, fails
from compare.cli import main
from compare.report.report import _PageWriter
from compare.results.run_info import read_run_info
from compare.run.campaign import RunConfig, plan_cells, select_policies
from compare.scenarios.sets import resolve_scenarios
from rl.policies.flights import FlightTasks, TrainingFlights, tasks_text
from rl.policies.folder import CURRICULUM, OBS_NORM, SHIPPED_POLICIES, PolicyFolder
from rl.training.checkpoints import RESUME_FILES
from rl.training.loop import command_line
from synthetic_run import write_run
from uam_fdm.city.plot import save_figure
from uam_fdm.files.strict import MAX_JSON_DEPTH, strict_json_loads

DEEP = 100_000  # levels: far beyond Python's recursion limit


def _deep(levels: int = DEEP) -> str:
    return "[" * levels + "]" * levels


@pytest.fixture
def no_training(monkeypatch: pytest.MonkeyPatch) -> None:
    """A resume that gets past its checks fails the test here, before anything is built or written."""
    def built(*_args: Any, **_kwargs: Any) -> None:
        raise AssertionError("the training run was built: the resume was not refused")

    monkeypatch.setattr(rl.training.loop, "_TrainingRun", built)


def _resumable(tmp_path: Path, vehicle: str = "small_quad") -> Path:
    """A copy of a shipped policy's files that resuming and flying read (no training flights)."""
    folder = tmp_path / f"resume-{vehicle}"
    folder.mkdir()
    for name in (*RESUME_FILES, CURRICULUM, OBS_NORM):
        shutil.copyfile(SHIPPED_POLICIES[vehicle] / name, folder / name)
    return folder


def _edit_json(path: Path, edit: Any) -> None:
    data = json.loads(path.read_text(encoding="utf-8"))
    edit(data)
    path.write_text(json.dumps(data), encoding="utf-8")


def _train(folder: Path, out: Path, *more: str) -> list[str]:
    return ["train", "--resume", str(folder), "--out", str(out), "--no-progress", *more]


# ---- 1. train --resume ---------------------------------------------------------------------------------------
def test_resume_from_a_folder_without_a_model_is_refused_before_anything_is_made(tmp_path, capsys, no_training):
    folder = _resumable(tmp_path)
    (folder / "model.zip").unlink()
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, str(folder), "model.zip is missing")
    assert not (tmp_path / "out").exists()


def test_resume_from_a_missing_folder_is_refused(tmp_path, capsys, no_training):
    fails(_train(tmp_path / "nowhere", tmp_path / "out"), capsys, tmp_path, "nowhere", "no such folder")


def test_resume_refuses_a_config_that_disagrees_with_the_weights(tmp_path, capsys, no_training):
    folder = _resumable(tmp_path)
    _edit_json(folder / "config.json", lambda d: d["ppo"].update(net_arch=[64, 64]))
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, "config.json", "ppo.net_arch", "[64, 64]", "128")


def test_resume_refuses_a_config_whose_observation_the_weights_do_not_take(tmp_path, capsys, no_training):
    folder = _resumable(tmp_path)
    _edit_json(folder / "config.json", lambda d: d["nav"]["observe"].update(history=3))
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, "config.json", "nav.observe", "115")


def test_resume_refuses_a_policy_of_another_vehicle(tmp_path, capsys, no_training):
    folder = _resumable(tmp_path, "uam_multicopter")
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, str(folder), "nav.vehicle", "'uam_multicopter'",
          "--vehicle uam_multicopter")


def test_resume_refuses_an_unreadable_curriculum_state(tmp_path, capsys, no_training):
    folder = _resumable(tmp_path)
    (folder / CURRICULUM).write_text(json.dumps({"difficulty": "hard"}), encoding="utf-8")
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, "curriculum.json", "difficulty", "hard")


def test_resume_refuses_another_ground_than_the_policy_was_trained_on(tmp_path, capsys, no_training):
    """A policy of generated cities resumed on a scenario's map, or one of a scenario resumed without it."""
    folder = _resumable(tmp_path)
    tiny = Path(__file__).resolve().parents[1] / "data" / "tiny_scenario.yaml"
    fails(_train(folder, tmp_path / "out", "--scenario", str(tiny)), capsys, tmp_path, str(folder),
          "trained on generated cities", repr(str(tiny)), "--scenario")
    _edit_json(folder / "config.json", lambda d: d.update(scenario="elsewhere.yaml"))
    fails(_train(folder, tmp_path / "out"), capsys, tmp_path, "trained on 'elsewhere.yaml'", "config.json's scenario")


def test_resume_refuses_another_seed_than_the_policy_was_trained_with(tmp_path, capsys, no_training):
    """The model carries its seed into the resumed run; a run built with another would refuse it only after building
    its environments (a minute of cities), or, unbatched, be seeded otherwise than its provenance says."""
    folder = _resumable(tmp_path)
    seed = json.loads((folder / "config.json").read_text(encoding="utf-8"))["seed"]
    fails(_train(folder, tmp_path / "out", "--seed", str(seed + 1)), capsys, tmp_path, str(folder),
          f"trained with seed {seed}", f"seed {seed + 1}", f"--seed {seed}")


def test_a_given_policy_is_not_called_none_given(tmp_path):
    """A scenario's vehicle file reusing a preset's name with other parameters: the note says why the policy given
    with --policy does not fly it, not that none was given."""
    mine = _resumable(tmp_path)
    quad = next(s for s in resolve_scenarios("default") if s.vehicle_name == "small_quad")
    heavier = replace(quad, vehicle=replace(quad.vehicle, mass_kg=quad.vehicle.mass_kg * 1.05))
    opts = RunConfig(out_dir=tmp_path / "run", policies=(mine,))
    _, notes = plan_cells([heavier], opts, select_policies([heavier], opts))
    assert len(notes) == 1 and "none given with --policy" not in notes[0]
    assert str(mine.resolve()) in notes[0] and "other parameters" in notes[0]


# ---- 2. numbers that overflow; drawing names the font lacks -----------------------------------------------
def test_reward_weights_that_overflow_the_returns_are_refused_naming_the_key(tmp_path, capsys):
    folder = _resumable(tmp_path)
    _edit_json(folder / "config.json", lambda d: d["nav"]["reward"].update(arrival_bonus=1e308))
    assert main(["evaluate-policy", str(folder), "--episodes", "2", "--no-baseline"]) == 2
    err = capsys.readouterr().err
    line = error_line(err)
    assert "config.json" in line and "reward.arrival_bonus" in line and "1e+308" in line
    assert err.strip() == line  # no warning of a library on stderr besides


@pytest.mark.parametrize("draw", ["png", "pdf"])
def test_a_name_the_font_cannot_draw_raises_no_warning(tmp_path, draw):
    fig = Figure()
    fig.suptitle("\U0001F643 \u6771\u4eac")  # an emoji and two CJK characters: not in matplotlib's default font
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        if draw == "png":
            save_figure(fig, tmp_path / "f.png")
        else:
            with PdfPages(tmp_path / "f.pdf") as pdf:
                _PageWriter(pdf, tmp_path / "figures").add(fig, "page")
    assert [str(w.message) for w in seen] == []


# ---- 3. training flights: non-finite numbers, deep nesting ---------------------------------------------------
def _flights_policy(tmp_path: Path) -> Path:
    """A policy folder holding the shipped small-quad policy's tasks and its first recorded checkpoint."""
    src = SHIPPED_POLICIES["small_quad"] / "training_flights"
    folder = tmp_path / "policy"
    (folder / "training_flights").mkdir(parents=True)
    for name in ("tasks.json", "step_00000000000.npz"):
        shutil.copyfile(src / name, folder / "training_flights" / name)
    return folder


def _view(folder: Path, tmp_path: Path) -> list[str]:
    return ["view-training", str(folder), "--out", str(tmp_path / "page.html")]


def test_a_non_finite_task_number_is_named_by_file_and_key(tmp_path, capsys):
    folder = _flights_policy(tmp_path)
    _edit_json(folder / "training_flights" / "tasks.json", lambda d: d["tasks"][3].update(timeout_s=float("inf")))
    fails(_view(folder, tmp_path), capsys, tmp_path, "tasks.json", "tasks[3].timeout_s", "inf")


def test_a_non_finite_flight_number_is_named_by_file_and_key(tmp_path, capsys):
    folder = _flights_policy(tmp_path)
    path = folder / "training_flights" / "step_00000000000.npz"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["min_clearance_m"] = arrays["min_clearance_m"].copy()
    arrays["min_clearance_m"][2] = np.nan
    np.savez(path, **arrays)
    fails(_view(folder, tmp_path), capsys, tmp_path, str(path), "min_clearance_m")


def test_unknown_air_of_a_task_is_written_as_null_and_read_back():
    tasks = TrainingFlights.open(SHIPPED_POLICIES["small_quad"]).tasks
    unknown = replace(tasks, tasks=tuple(replace(t, elevation_m=float("nan"), isa_offset_k=float("nan"))
                                         for t in tasks.tasks))
    text = tasks_text(unknown)
    assert "NaN" not in text and json.loads(text)["tasks"][0]["elevation_m"] is None
    back = FlightTasks.from_dict(strict_json_loads(text))
    assert np.isnan(back.tasks[0].elevation_m) and np.isnan(back.tasks[0].isa_offset_k)


def test_deeply_nested_tasks_json_is_refused_naming_it(tmp_path, capsys):
    folder = _flights_policy(tmp_path)
    path = folder / "training_flights" / "tasks.json"
    path.write_text(_deep(), encoding="utf-8")
    fails(_view(folder, tmp_path), capsys, tmp_path, str(path), f"deeper than {MAX_JSON_DEPTH} levels")


@pytest.mark.parametrize("name", ["config.json", "provenance.json"])
def test_deeply_nested_policy_json_is_refused_naming_it(tmp_path, name):
    folder = tmp_path / "policy"
    folder.mkdir()
    (folder / name).write_text(_deep(), encoding="utf-8")
    read = PolicyFolder(folder).config if name == "config.json" else PolicyFolder(folder).provenance
    with pytest.raises(ValueError, match=rf"{re.escape(str(folder / name))}: .*deeper than {MAX_JSON_DEPTH}"):
        read()


def test_deeply_nested_run_json_is_refused_naming_it(tmp_path):
    run = tmp_path / "run"
    write_run(run, None)
    (run / "run.json").write_text('{"a": ' + _deep() + "}", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"run\.json: .*deeper than {MAX_JSON_DEPTH}"):
        read_run_info(run)


def test_the_depth_limit_counts_brackets_only_outside_strings():
    assert strict_json_loads(json.dumps({"rule": "[" * 1000, "x": [[1]]})) == {"rule": "[" * 1000, "x": [[1]]}
    nested: Any = 1
    for _ in range(MAX_JSON_DEPTH - 1):
        nested = [nested]
    assert strict_json_loads(json.dumps({"k": nested})) == {"k": nested}  # exactly the limit
    with pytest.raises(ValueError, match="deeper than"):
        strict_json_loads(json.dumps({"k": [nested]}))


# ---- 4. provenance without the machine's paths -------------------------------------------------------------
def _strings(value: Any) -> list[str]:
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (k, *_strings(v))]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return [value] if isinstance(value, str) else []


@pytest.mark.parametrize("vehicle", sorted(SHIPPED_POLICIES))
def test_shipped_provenance_holds_no_absolute_path(vehicle):
    prov = json.loads((SHIPPED_POLICIES[vehicle] / "provenance.json").read_text(encoding="utf-8"))
    words = [w for s in _strings(prov) for w in s.split()]
    absolute = [w for w in words if w.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:[\\/]", w)]
    assert absolute == []
    assert f" --out rl/policies/{SHIPPED_POLICIES[vehicle].name} " in prov["command"]  # as a user in a checkout


def test_the_recorded_command_keeps_out_as_typed_and_the_program_by_name(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/opt/venv/bin/uam-compare", "train", "--out", "runs/mine", "--seed", "3"])
    assert command_line() == "uam-compare train --out runs/mine --seed 3"


# ---- 5. training flights: small files, big memory; links in a policy folder ----------------------------------
def _rewrite_checkpoint(path: Path, edit: Any) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    from uam_fdm.files.npz import write_npz

    write_npz(path, arrays)


def _longer_first_flight(samples: int) -> Any:
    """An edit making the first flight `samples` long (zeros: they compress a thousandfold)."""
    def edit(a: dict[str, np.ndarray]) -> None:
        off = a["offsets"]
        extra = samples - int(off[1] - off[0])
        for k in ("pos_m", "vel_m_s", "clearance_m"):
            pad = np.zeros((extra, *a[k].shape[1:]), a[k].dtype)
            a[k] = np.concatenate([a[k][:off[1]], pad, a[k][off[1]:]])
        a["offsets"] = np.concatenate([off[:1], off[1:] + extra])

    return edit


def test_a_checkpoint_that_inflates_past_the_cap_is_refused_unread(tmp_path, capsys, monkeypatch):
    """A checkpoint of a few hundred kB whose arrays inflate to many MB: refused by name from the sizes its zip
    directory declares, before any array is read (the cap lowered here; the shipped checkpoints are far below it)."""
    import rl.policies.flights as flights_module

    folder = _flights_policy(tmp_path)
    path = folder / "training_flights" / "step_00000000000.npz"
    _rewrite_checkpoint(path, _longer_first_flight(300_000))  # 8.4 MB of arrays in a small file
    monkeypatch.setattr(flights_module, "MAX_CHECKPOINT_BYTES", 4 * 2**20, raising=False)
    read: list[str] = []
    real = np.load
    monkeypatch.setattr(np, "load", lambda file, *args, **kwargs: read.append(str(file)) or real(file, *args, **kwargs))
    line = fails(_view(folder, tmp_path), capsys, tmp_path, str(path), "refused unread", "at most 4 MiB")
    assert "MiB in memory" in line and str(path) not in read


def test_a_checkpoint_array_that_claims_more_than_it_holds_is_refused_by_name(tmp_path, capsys):
    """An array header claiming 10**12 samples in a member of a few bytes: refused naming the array (before: numpy
    set out to allocate terabytes)."""
    import io
    import zipfile

    folder = _flights_policy(tmp_path)
    path = folder / "training_flights" / "step_00000000000.npz"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 3)})
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["pos_m.npy"] = header.getvalue() + b"\0" * 64  # (the header holds the format's magic)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for n, data in members.items():
            z.writestr(n, data)
    fails(_view(folder, tmp_path), capsys, tmp_path, str(path), "'pos_m.npy' claims")


def test_a_long_flight_is_drawn_with_at_most_the_stated_samples(tmp_path):
    """A recorded flight of 40,000 samples (800 s at 50 Hz, within the reader's cap): the page draws it with at
    most `max_points_per_flight` samples, its last one kept (before: every 5th, 8,001)."""
    from compare.pages.training_view import TrainingViewConfig, training_payload

    folder = _flights_policy(tmp_path)
    path = folder / "training_flights" / "step_00000000000.npz"
    _rewrite_checkpoint(path, _longer_first_flight(40_000))
    cap = TrainingViewConfig().max_points_per_flight
    (checkpoint,) = training_payload(folder)["checkpoints"]
    assert checkpoint["timesteps"] == 0
    (first, *rest) = checkpoint["flights"]
    assert cap <= 2_000 and len(first["x"]) <= cap + 1 and first["x"][-1] == 0.0
    assert all(len(f["x"]) <= cap + 1 for f in rest)


def test_training_flights_are_never_written_through_a_link_in_the_policy_folder(tmp_path):
    """`POLICY/training_flights` a link to a user's folder: the recorder's writers refuse it, naming the link,
    and write nothing there."""
    from rl.policies.flights import write_tasks
    from uam_fdm.files.inside import LinkInFolder

    folder = _flights_policy(tmp_path)
    tasks = TrainingFlights.open(folder).tasks
    home = tmp_path / "home"
    shutil.move(folder / "training_flights", home)
    (folder / "training_flights").symlink_to(home, target_is_directory=True)
    before = {p.name: p.read_bytes() for p in home.iterdir()}
    with pytest.raises(LinkInFolder, match="training_flights: a symbolic link inside"):
        write_tasks(folder, tasks)
    assert {p.name: p.read_bytes() for p in home.iterdir()} == before
