"""A run flown on sensors with a wrong map, end to end through the CLI: the levels reach run.json, metrics.csv, the
fairness statement and the report; the run folder keeps the pilots' prior map beside the true city with the same
building ids; the viewer draws what the prior map lacks, the estimated paths and the lidar hits."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from pypdf import PdfReader

from compare.cli import main
from compare.pages.viewer import ViewerConfig, group_payload
from compare.playback.flights import flight_groups
from compare.results.store import read_episode_table
from run_data import TINY
from uam_fdm.city.mapfile import load_map_file

FLY = ["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--videos", "none", "--no-progress", "--seeds", "0",
       "--sensing", "degraded", "--map-error", "wrong"]


@pytest.fixture(scope="module")
def sensed_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sensed") / "run"
    assert main([*FLY, "--out", str(out)]) == 0
    return out


def test_the_levels_are_recorded_everywhere(sensed_run):
    info = json.loads((sensed_run / "run.json").read_text())
    (sc,) = info["scenarios"]
    assert (sc["sensing"], sc["map_error"]) == ("degraded", "wrong")
    assert "At degraded sensing each decision gets the navigation filter's estimate" in info["fairness"]
    assert "perfect state estimation" not in info["fairness"]
    with open(sensed_run / "metrics.csv", newline="") as f:
        (row,) = list(csv.DictReader(f))
    assert (row["sensing"], row["map_error"]) == ("degraded", "wrong")
    assert float(row["est_error_h_rms_m"]) > 0.0 and 0.0 <= float(row["gnss_availability"]) <= 1.0
    assert row["min_clearance_unmapped_m"] != "nan"
    # how many unmapped obstacles the lidar sensed, and how far off at first: in metrics.csv and in the store
    sensed = float(row["unmapped_sensed"])
    assert sensed >= 0.0 and (sensed == 0.0) == (row["unmapped_first_sensed_m_min"] == "nan")
    (stored,) = read_episode_table(sensed_run)
    for name in ("unmapped_sensed", "unmapped_first_sensed_m_min", "unmapped_first_sensed_m_median"):
        assert repr(stored[name]) == row[name], name
    text = "".join(page.extract_text() for page in PdfReader(sensed_run / "report.pdf").pages)
    assert "sensing degraded · map error wrong" in text


def test_the_prior_map_is_kept_with_the_citys_ids(sensed_run):
    city = load_map_file(sensed_run / "maps" / "tiny.yaml")
    prior = load_map_file(sensed_run / "maps" / "prior" / "tiny.yaml")
    city_ids, prior_ids = set(city.building_ids.tolist()), set(prior.building_ids.tolist())
    assert prior_ids < city_ids  # buildings missing from the prior, cranes and masts added to the truth
    assert any(b.base_m > 0.0 for b in city.buildings)  # a crane's jib stands off the ground, as flown


def test_the_viewer_draws_belief_beside_truth(sensed_run):
    (group,) = flight_groups(sensed_run)
    assert group.prior is not None and group.unmapped_ids
    fig = group_payload(group, ViewerConfig())["figure"]
    names = [t.get("name", "") for t in fig["data"]]
    assert "not in the prior map" in names
    assert any(n.endswith("estimated path") for n in names)
    lidar = [t for t in fig["data"] if t.get("name", "").endswith("lidar hits")]
    assert lidar and lidar[0]["visible"] == "legendonly" and len(lidar[0]["x"]) > 100
    # the pilots' traces keep their places (the page's script moves traces 3 + 3k + 1 and + 2)
    assert names[0] == "buildings" and names[1:3] == ["start", "goal"] and names[3].endswith("path")
