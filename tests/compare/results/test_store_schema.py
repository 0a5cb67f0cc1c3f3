"""The store's description (RUN_DIR/store/schema.json and SCHEMA.md) is written with every run, comes from the code's
own column definitions, and matches the Parquet files column for column: name, order, type, nullability; every
column says what it holds, and its unit agrees with its name."""
from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from compare.results.metrics import EpisodeMetrics
from compare.results.store import samples_files, store_dir
from compare.results.store_schema import SCHEMA_JSON, SCHEMA_MD, describe_store, type_name
from compare.results.tables import EPISODE_SCHEMA, SAMPLE_SCHEMA

SUFFIX_UNITS = {"_m_s": "m/s", "_rad_s": "rad/s", "_kg_m3": "kg/m^3", "_kj": "kJ", "_w": "W", "_ms_median": "ms",
                "_ms_p95": "ms", "_ms_mean": "ms", "_ms_max": "ms", "_m": "m", "_s": "s"}


def _columns(table: str) -> list[dict]:
    return describe_store()["tables"][table]["columns"]


def _check_file(path: Path, columns: list[dict]) -> None:
    schema = pq.read_schema(path)
    assert [c["name"] for c in columns] == schema.names, path
    for c, field in zip(columns, schema):
        assert (c["type"], c["nullable"]) == (type_name(field.type), field.nullable), (path, c["name"])


def test_every_run_writes_the_description_of_its_store_matching_its_files(flown_tiny_run: Path) -> None:
    store = store_dir(flown_tiny_run)
    written = json.loads((store / SCHEMA_JSON).read_text(encoding="utf-8"))
    assert written == describe_store()
    _check_file(store / "episodes.parquet", written["tables"]["episodes"]["columns"])
    [samples] = samples_files(flown_tiny_run)
    _check_file(samples, written["tables"]["samples"]["columns"])
    markdown = (store / SCHEMA_MD).read_text(encoding="utf-8")
    for table in ("episodes", "samples"):
        for c in written["tables"][table]["columns"]:
            assert f"\n| {c['name']} | {c['type']} | {c['unit']} |" in markdown, c["name"]
    view = written["views"]["decisions"]["columns"]
    assert set(view) <= set(SAMPLE_SCHEMA.names) and "action" in view and "observation" in view


def test_the_schemas_are_built_from_the_described_columns() -> None:
    for table, schema in (("episodes", EPISODE_SCHEMA), ("samples", SAMPLE_SCHEMA)):
        assert [(c["name"], c["type"], c["nullable"]) for c in _columns(table)] == [
            (f.name, type_name(f.type), f.nullable) for f in schema]
    assert type_name(SAMPLE_SCHEMA.field("action").type) == "list<float32>"
    assert type_name(SAMPLE_SCHEMA.field("t_s").type) == "float64"


@pytest.mark.parametrize("table", ["episodes", "samples"])
def test_every_column_says_what_it_holds_and_its_unit_agrees_with_its_name(table: str) -> None:
    for c in _columns(table):
        assert len(c["description"]) > 10, c["name"]
        suffix = next((s for s in SUFFIX_UNITS if c["name"].endswith(s)), None)
        if suffix is not None:
            assert c["unit"] == SUFFIX_UNITS[suffix], c
        if c["name"].endswith(("_e_m_s", "_n_m_s", "_u_m_s")) or c["name"] in ("x_m", "vx_m_s", "action"):
            assert c["frame"] == "world ENU", c
        if c["name"].startswith("w") and c["name"].endswith("_rad_s") and len(c["name"]) == 8:
            assert c["frame"] == "body FLU", c


def test_a_metric_is_described_by_its_own_docstring() -> None:
    described = {c["name"]: c for c in _columns("episodes")}
    doc = EpisodeMetrics.__doc__ or ""
    assert described["spl"]["description"].startswith("success weighted by path length") and "spl:" in doc
    # two entries on one line of the docstring ("map: the city's name. vehicle: the vehicle preset name.")
    assert described["map"]["description"] == "the city's name."
    assert described["vehicle"]["description"] == "the vehicle preset name."
    # one entry naming several fields, continued over lines
    assert described["replans_tracking"]["description"] == described["replans_clearance"]["description"]
    assert described["replans_clearance"]["description"].endswith("[count].")
    assert described["energy_kj"]["unit"] == "kJ" and described["success"]["unit"] == ""
