"""The run store's columns, defined once: their Parquet types and what they hold (unit, frame, meaning).

`SAMPLE_COLUMNS` and `EPISODE_COLUMNS` are the one definition of the store's two tables: `compare.results.tables`
builds its Parquet schemas from them (`SAMPLE_SCHEMA`, `EPISODE_SCHEMA`), and every run writes their description
into its store (`write_schema`: `RUN_DIR/store/schema.json` for programs, `RUN_DIR/store/SCHEMA.md` for people).
The metrics.csv columns of the episode table are described by `compare.results.metrics.EpisodeMetrics`'s own
docstring (its "Attributes:" section, read here), so a metric is documented where it is defined.

Frames: world ENU (x east, y north, z up) [m], body FLU (x forward, y left, z up); SI units throughout.
"""
from __future__ import annotations

import inspect
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import pyarrow as pa

from compare.results.metrics import EpisodeMetrics
from uam_fdm.files.atomic import write_text_atomic

SCHEMA_JSON, SCHEMA_MD = "schema.json", "SCHEMA.md"
SCHEMA_VERSION = 2
"""1: the store as first written; 2: with the decisions' commands and observations (`DECISION_COLUMNS`)."""
WORLD, BODY = "world ENU", "body FLU"
ROTOR_SPEEDS, VELOCITY_YAW = "rotor_speeds_rad_s", "velocity_enu_m_s_yaw_rad"
"""The values of `action_kind`: a decision commanded rotor speeds, or a velocity and heading."""


@dataclass(frozen=True)
class Column:
    """One column of a store table.

    Attributes:
        name: the column's name (units as suffixes where they apply: `_m`, `_m_s`, `_rad_s`).
        type: its Parquet (Arrow) type.
        unit: its unit ("" for names and flags, "-" for a ratio, "count").
        frame: the frame of a vector's component ("world ENU", "body FLU"; "" for a scalar).
        description: what it holds.
        nullable: it may be null (and where, the description says).
    """

    name: str
    type: pa.DataType
    unit: str = ""
    frame: str = ""
    description: str = ""
    nullable: bool = False

    @property
    def field(self) -> pa.Field:
        """The column as a Parquet (Arrow) field."""
        return pa.field(self.name, self.type, self.nullable)


def schema_of(columns: Sequence[Column]) -> pa.Schema:
    """The Parquet (Arrow) schema of a table of `columns`, in their order."""
    return pa.schema([c.field for c in columns])


_F32, _F64, _LIST32 = pa.float32(), pa.float64(), pa.list_(pa.float32())
KEY_COLUMNS = (Column("scenario", pa.string(), description="the scenario's name"),
               Column("episode", pa.int32(), description="the episode's index in its scenario"),
               Column("method", pa.string(), description="the pilot's name"),
               Column("seed", pa.int64(), description="the seed of the cell"))


def _xyz(names: Sequence[str], type_: pa.DataType, unit: str, frame: str, what: str,
         nullable: bool = False) -> tuple[Column, ...]:
    return tuple(Column(n, type_, unit, frame, f"{what}, {axis} component", nullable)
                 for n, axis in zip(names, ("x (east)" if frame == WORLD else "x", "y (north)" if frame == WORLD
                                            else "y", "z (up)" if frame == WORLD else "z")))


DECISION_COLUMNS = (
    Column("action_kind", pa.string(), "", "", f"what the decision at this row commanded: {ROTOR_SPEEDS!r} (rotor "
           f"speeds, flown as given) or {VELOCITY_YAW!r} (a velocity and heading for the vehicle's low-level "
           "controller); null on rows without a decision", True),
    Column("action", _LIST32, "rad/s, or m/s and rad", WORLD, "the decision's command: one speed per rotor [rad/s] "
           "(rotor order of the vehicle file), or [v_east, v_north, v_up, yaw] (velocity [m/s] world ENU, heading "
           "[rad] from east, counter-clockwise); rounded as rotor_speed_rad_s and the velocity are; null on rows "
           "without a decision", True),
    Column("action_hold_periods", pa.int32(), "count", "", "control periods the command is held (the learned pilot: "
           "its policy's decision period); null on rows without a decision", True),
    Column("observation", _LIST32, "-", "", "the pilot's own observation vector at the decision (the learned pilot: "
           "its policy's raw input before normalisation, `rl.sensing.observation`); null for a pilot that has none "
           "and on rows without a decision", True))

SAMPLE_COLUMNS: tuple[Column, ...] = (
    *KEY_COLUMNS,
    Column("t_s", _F64, "s", "", "time since the episode's start"),
    *_xyz(("x_m", "y_m", "z_m"), _F64, "m", WORLD, "position of the vehicle's centre of mass"),
    *_xyz(("vx_m_s", "vy_m_s", "vz_m_s"), _F32, "m/s", WORLD, "velocity"),
    *(Column(n, _F32, "-", "", f"attitude quaternion body FLU -> world ENU, {n[1]} component") for n in
      ("qw", "qx", "qy", "qz")),
    *_xyz(("wx_rad_s", "wy_rad_s", "wz_rad_s"), _F32, "rad/s", BODY, "body rates"),
    Column("rotor_speed_rad_s", _LIST32, "rad/s", "", "rotor speeds, one per rotor (rotor order of the vehicle file)"),
    Column("rotor_command_rad_s", _LIST32, "rad/s", "", "rotor-speed commands applied during the physics step ending "
           "at this row (row 0: the hover trim the episode starts from)"),
    *_xyz(("wind_e_m_s", "wind_n_m_s", "wind_u_m_s"), _F32, "m/s", WORLD, "wind the vehicle flew in (held per "
          "control period)"),
    Column("clearance_m", _F32, "m", "", "signed distance from the vehicle's collision sphere to the nearest building "
           "or the ground (negative: a collision)"),
    Column("shaft_power_w", _F32, "W", "", "total rotor shaft power, sum of Q_i * Omega_i; null in an episode saved "
           "before it was recorded", True),
    Column("decision_t_s", _F64, "s", "", "time of the pilot's decision at this row (the start of its control "
           "period); null on rows without a decision", True),
    Column("compute_s", _F32, "s", "", "wall time the decision took; null on rows without a decision", True),
    *_xyz(("est_x_m", "est_y_m", "est_z_m"), _F64, "m", WORLD, "the navigation estimate's position (null at "
          "perfect sensing: the pilot flies on the truth)", True),
    Column("lidar_hits_m", _LIST32, "m", WORLD, "at the first row at or after each lidar scan, a thinned set of its "
           "true hit points, flattened [x, y, z, ...] (null elsewhere and at perfect sensing)", True),
    *DECISION_COLUMNS)
"""The samples table, one row per kept sample (row 0, the end of every control period and the physics step of
least clearance; every physics step with `run --store full`)."""

_METRIC_TYPES = {"str": pa.string(), "int": pa.int64(), "float": _F64, "bool": pa.bool_()}
_SUFFIX_UNITS = (("_kj", "kJ"), ("_ms_mean", "ms"), ("_ms_max", "ms"), ("_m", "m"), ("_s", "s"))
_ENTRY = re.compile(r"^(?P<names>[a-z_0-9]+(?:, [a-z_0-9]+)*): (?P<text>.*)$")
_INLINE = re.compile(r"(?<=\.) (?P<names>[a-z_0-9]+(?:, [a-z_0-9]+)*): ")


def _attribute_docs(cls: type) -> dict[str, str]:
    """The descriptions of a dataclass's fields in its docstring's "Attributes:" section, by field name (an entry
    may name several fields, "a, b: text"; one line may hold two entries, "a: text. b: text")."""
    names = {f.name for f in fields(cls)}
    doc = inspect.cleandoc(cls.__doc__ or "")
    section = doc.split("Attributes:", 1)[1] if "Attributes:" in doc else ""
    entries: list[list[str]] = []
    for line in section.splitlines():
        text = line.strip()
        m = _ENTRY.match(text) if line.startswith("    ") and not line.startswith("     ") else None
        if m and set(m["names"].split(", ")) <= names:
            entries.append([m["names"], m["text"]])
        elif line.startswith("     ") and entries:
            entries[-1][1] += " " + text
        else:  # a paragraph of its own: not an entry
            entries.append(["", text])
    out: dict[str, str] = {}
    for head, text in entries:
        start = 0
        for m in _INLINE.finditer(text):  # "a: text. b: text": cut where a sentence starts with field names
            if set(m["names"].split(", ")) <= names:
                out.update(dict.fromkeys(head.split(", ") if head else (), text[start:m.start()].strip()))
                head, start = m["names"], m.end()
        out.update(dict.fromkeys(head.split(", ") if head else (), text[start:].strip()))
    return out


def _unit(name: str, text: str) -> str:
    """A metric's unit: the first "[unit]" of its description, else its name's suffix ("" for none)."""
    m = re.search(r"\[([^\]]+)\]", text)
    if m:
        return m[1]
    return next((u for suffix, u in _SUFFIX_UNITS if name.endswith(suffix)), "")


def _metric_columns() -> tuple[Column, ...]:
    docs = _attribute_docs(EpisodeMetrics)
    return tuple(Column(f.name, _METRIC_TYPES[str(f.type)], _unit(f.name, docs.get(f.name, "")), "",
                        docs.get(f.name, "")) for f in fields(EpisodeMetrics))


CONDITION_COLUMNS = (
    Column("turbulence", pa.string(), "", "", "the turbulence level's name", True),
    Column("field_density_kg_m3", _F64, "kg/m^3", "", "air density at the field (run.json's, rounded to 4 decimals)",
           True),
    Column("density_altitude_m", _F64, "m", "", "the ISA altitude of that density", True),
    Column("steady_wind_m_s", _F64, "m/s", "", "the steady wind's speed at its reference height", True),
    *_xyz(("steady_wind_e_m_s", "steady_wind_n_m_s", "steady_wind_u_m_s"), _F64, "m/s", WORLD,
          "the steady wind at its reference height", True),
    Column("building_coverage", _F64, "-", "", "share of the map's ground area under building footprints", True))
"""The air and city an episode flew in (null where not recorded)."""

EPISODE_COLUMNS: tuple[Column, ...] = (
    *_metric_columns(), *CONDITION_COLUMNS,
    Column("store", pa.string(), "", "", "how its samples were kept: 'control' (the control rate, rounded) or 'full' "
           "(every physics step)"),
    Column("samples", pa.int64(), "count", "", "how many samples it has"),
    Column("samples_file", pa.string(), "", "", "the samples file holding them, in the store folder"),
    Column("row_start", pa.int64(), "", "", "its first sample's row in that file"),
    Column("meta_json", pa.string(), "", "", "the episode's metadata as JSON (task, vehicle, seeds, the pilot's "
           "end-of-episode report)"))
"""The episode table, one row per episode: the metrics.csv columns (same names and order, described by
`EpisodeMetrics`), the conditions, and where its samples are."""

STATE_COLUMNS = ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "qw", "qx", "qy", "qz", "wx_rad_s", "wy_rad_s",
                 "wz_rad_s", "rotor_speed_rad_s")
DECISIONS_VIEW = (*(c.name for c in KEY_COLUMNS), "decision_t_s", "compute_s", *STATE_COLUMNS, "est_x_m", "est_y_m",
                  "est_z_m", *(c.name for c in DECISION_COLUMNS))
"""The columns of `load_run`'s decisions table: the samples rows where the pilot decided (the state at that row is
the true state at the decision; what the pilot was given is that state at perfect sensing, else its estimate)."""


_TYPE_NAMES = {"float": "float32", "double": "float64", "bool": "boolean"}


def type_name(t: pa.DataType) -> str:
    """A Parquet (Arrow) type as the description names it: "float32", "int64", "string", "list<float32>"."""
    if pa.types.is_list(t):
        return f"list<{type_name(t.value_type)}>"
    return _TYPE_NAMES.get(str(t), str(t))


def _column_json(c: Column) -> dict[str, Any]:
    return {"name": c.name, "type": type_name(c.type), "nullable": c.nullable, "unit": c.unit, "frame": c.frame,
            "description": c.description}


def describe_store() -> dict[str, Any]:
    """The store's description (what `RUN_DIR/store/schema.json` holds): every table, column, type, unit, frame."""
    return {
        "format": "uam-compare run store", "version": SCHEMA_VERSION,
        "frames": {WORLD: "x east, y north, z up [m]", BODY: "x forward, y left, z up"},
        "tables": {
            "episodes": {"files": "episodes.parquet", "rows": "one per episode, in cell order (scenario, episode, "
                         "method, seed)", "columns": [_column_json(c) for c in EPISODE_COLUMNS]},
            "samples": {"files": "samples-GGGG-KKK.parquet (compacted), parts/<cell>.parquet (not yet compacted)",
                        "rows": "one per kept sample of each episode, in cell order; a file written before a "
                        "nullable column existed lacks it (load_run gives it as nulls)",
                        "columns": [_column_json(c) for c in SAMPLE_COLUMNS]}},
        "views": {"decisions": {"from": "samples", "rows": "where decision_t_s is not null (one per decision)",
                                "columns": list(DECISIONS_VIEW),
                                "reader": "compare.results.run_tables.load_run(RUN_DIR).decisions"}}}


def schema_markdown() -> str:
    """The store's description as Markdown (what `RUN_DIR/store/SCHEMA.md` holds)."""
    d = describe_store()
    lines = [f"# The run store (version {d['version']})", "",
             "Written by uam-compare from its own column definitions (`compare/results/store_schema.py`); "
             "read it with `compare.results.run_tables.load_run(RUN_DIR)`, or with pandas, polars or DuckDB. "
             "Frames: " + "; ".join(f"{k}: {v}" for k, v in d["frames"].items()) + ".", ""]
    for name, table in d["tables"].items():
        lines += [f"## {name}", "", f"Files: {table['files']}. Rows: {table['rows']}.", "",
                  "| column | type | unit | frame | nullable | description |", "|---|---|---|---|---|---|"]
        lines += [f"| {c['name']} | {c['type']} | {c['unit']} | {c['frame']} | {'yes' if c['nullable'] else 'no'} "
                  f"| {c['description'].replace('|', '/')} |" for c in table["columns"]]
        lines.append("")
    view = d["views"]["decisions"]
    lines += ["## decisions (a view of samples)", "", f"Rows: the samples {view['rows']}; columns: "
              + ", ".join(view["columns"]) + f". Read as `{view['reader']}`.", ""]
    return "\n".join(lines)


def write_schema(folder: Path, root: Path) -> tuple[Path, Path]:
    """Write the store's description into its folder (schema.json and SCHEMA.md, atomically; `root`: the run
    folder, below which no link is followed); returns both paths."""
    text = json.dumps(describe_store(), indent=1, ensure_ascii=False) + "\n"
    return (write_text_atomic(Path(folder) / SCHEMA_JSON, text, root=root),
            write_text_atomic(Path(folder) / SCHEMA_MD, schema_markdown(), root=root))
