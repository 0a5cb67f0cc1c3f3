"""Authoring scenarios from the command line: `maps FILE` draws a scenario's city, legs and flight volume (a bad
file is refused before anything is drawn), `maps [OUT_DIR]` still draws the shipped maps, `validate` says when legs
are drawn at random, a generated city is named by its generator and seed, and `list` names every set, map,
vehicle, pilot and shipped policy, as text or JSON, without loading PyTorch, matplotlib or OMPL."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

import uam_fdm.city.plot
from cli_checks import fails
from compare.cli import main
from compare.flying.pilots import PILOT_NAMES
from compare.scenarios.sets import builtin_sets
from rl.policies.folder import SHIPPED_POLICIES
from run_data import TINY
from uam_fdm.city.mapfile import named_maps
from uam_fdm.vehicle.params import preset_names

ROOT = Path(__file__).resolve().parents[3]
SLOW_TO_IMPORT = ("torch", "matplotlib", "ompl", "stable_baselines3", "plotly", "ray", "pyarrow")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _scenario(tmp_path: Path, name: str = "drawn.yaml", **changes: Any) -> Path:
    """The tiny scenario with top-level keys changed (None: the key left out), written to `name`."""
    data = yaml.safe_load(TINY.read_text())
    data.update(changes)
    data = {k: v for k, v in data.items() if v is not None}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _must_not_run(what: str):
    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"{what} before the input was refused")
    return refuse


# ---- maps SCENARIO.yaml ---------------------------------------------------------------------------------------
def test_maps_draws_each_scenario_file_to_a_png(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    wrong = _scenario(tmp_path, "wrong.yaml", map_error="wrong",
                      episodes={"random": 3, "min_length_m": 40.0, "max_length_m": 90.0})
    out = tmp_path / "previews"
    assert main(["maps", str(TINY), str(wrong), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / "scenario_tiny_scenario.png"), str(out / "scenario_wrong.png")]
    for path in printed:
        assert Path(path).read_bytes()[:8] == PNG_SIGNATURE


def test_the_preview_draws_the_legs_the_volume_and_the_prior_maps_differences(tmp_path: Path) -> None:
    from compare.scenarios.scenario import load_scenario

    sc = load_scenario(_scenario(tmp_path, map_error={"preset": "wrong", "cranes": 1, "masts": 0}))
    only, changed = uam_fdm.city.plot.prior_differences(sc.city, sc.prior_map)
    assert {p.id for p in only} == set(sc.unmapped_ids) and changed  # 'wrong' moves every prior footprint
    fig = uam_fdm.city.plot.task_preview_figure(sc.city, [ep.task for ep in sc.episodes], prior=sc.prior_map,
                                                labels=["0"], title="t")
    top, _, side = fig.axes  # top view, its colour bar, the 3D view
    assert side.name == "3d" and top.get_xlim()[0] < 0.0 < 160.0 < top.get_xlim()[1]  # the whole volume
    texts = [t.get_text() for t in top.texts]
    assert "0" in texts  # the start's label: the episode index
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("not in the prior map" in t for t in legend) and any("goal radius" in t for t in legend)


def test_a_bad_scenario_file_is_refused_before_anything_is_drawn(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(uam_fdm.city.plot, "task_preview_figure", _must_not_run("a preview was drawn"))
    bad = _scenario(tmp_path, "bad.yaml", episodes={"random": 2, "lenght_m": 3})
    fails(["maps", str(TINY), str(bad), "--out", str(tmp_path / "out")], capsys, tmp_path, str(bad),
          "episodes.lenght_m", "unknown key")
    fails(["maps", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "out")], capsys, tmp_path, "missing.yaml")


def test_maps_refuses_a_folder_beside_scenario_files(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    fails(["maps", str(TINY), str(tmp_path / "out")], capsys, tmp_path, "give either OUT_DIR or scenario files")
    fails(["maps", str(tmp_path / "a"), "--out", str(tmp_path / "b")], capsys, tmp_path, "give the output folder once")


def test_maps_without_files_still_draws_the_shipped_maps(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[Path] = []

    def render(out_dir: Path) -> list[Path]:
        asked.append(Path(out_dir))
        return [Path(out_dir) / "map_suburb.png"]

    monkeypatch.setattr(uam_fdm.city.plot, "render_named_maps", render)
    assert main(["maps", str(tmp_path / "shipped")]) == 0
    assert main(["maps", "--out", str(tmp_path / "other")]) == 0
    assert asked == [tmp_path / "shipped", tmp_path / "other"]
    assert capsys.readouterr().out.split() == [str(tmp_path / "shipped" / "map_suburb.png"),
                                               str(tmp_path / "other" / "map_suburb.png")]


# ---- validate, generated city names -------------------------------------------------------------------------
def test_validate_says_the_legs_are_drawn_and_names_a_generated_city_by_generator_and_seed(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = _scenario(tmp_path, map={"generator": {"preset": "suburb", "seed": 42}}, bounds=None,
                     episodes={"random": 2, "seed": 7})
    assert main(["validate", str(path)]) == 0
    line = capsys.readouterr().out.strip()
    assert "map gen-suburb-42 with" in line  # not "suburb", the shipped map's name
    assert "2 episodes x 1 seeds" in line and "legs drawn at random from seed 7" in line


# ---- list -----------------------------------------------------------------------------------------------------
def test_list_names_every_set_map_vehicle_pilot_and_policy(capsys: pytest.CaptureFixture) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0] for line in out.splitlines() if line.startswith("  ")}
    for name in (*builtin_sets(), *named_maps(), *preset_names(), *PILOT_NAMES, *SHIPPED_POLICIES, "module:Class"):
        assert name in rows, name
    assert "rl/policies/default" in out  # a path as the repository names it, not this machine's


def test_list_json_is_one_object_of_named_described_items(capsys: pytest.CaptureFixture) -> None:
    assert main(["list", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert list(data) == ["sets", "maps", "vehicles", "pilots", "policies"]
    assert all(isinstance(i["name"], str) and i["description"] for items in data.values() for i in items)
    assert [s["name"] for s in data["sets"]] == builtin_sets()
    assert {s["name"]: s["kind"] for s in data["sets"]}["default"] == "folder"
    assert [m["name"] for m in data["maps"]] == named_maps()
    assert [v["name"] for v in data["vehicles"]] == preset_names()
    pilots = {p["name"]: p for p in data["pilots"]}
    assert [n for n, p in pilots.items() if p["kind"] == "built-in"] == list(PILOT_NAMES)
    assert pilots["ppo"]["default"] is True and pilots["apf"]["default"] is False
    assert {p["name"]: p["path"] for p in data["policies"]} == {"small_quad": "rl/policies/default",
                                                                "uam_multicopter": "rl/policies/uam"}


def test_list_loads_no_slow_package() -> None:
    code = ("import json, sys\nfrom compare.cli import main\nrc = main(['list', '--json'])\n"
            "print(json.dumps([rc, sorted(sys.modules)]))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    rc, modules = json.loads(done.stdout.strip().splitlines()[-1])
    assert rc == 0, done.stderr
    assert sorted(m for m in modules if m.split(".")[0] in SLOW_TO_IMPORT) == []
