"""Rewrite tiny_metrics.json from a fresh run of tests/data/tiny_scenario.yaml (both pilots).

Run after a deliberate change of physics, planner or policy, and say why in the commit:

    python tests/golden/regenerate.py
"""
from __future__ import annotations

import csv
import json
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).parent
COLUMNS = ("outcome", "success", "collision", "min_clearance_m", "time_s", "path_length_m", "energy_kj",
           "time_below_5m_s")
# Same machine: bit-identical. Other machines/compilers/libm: small float drift, amplified over a
# closed-loop flight; these bounds still catch any real change of behaviour.
TOLERANCES = {"min_clearance_m": 0.05, "time_s": 0.1, "path_length_m": 0.5, "energy_kj": 0.05,
              "time_below_5m_s": 0.2}


def main() -> int:
    from compare.cli import main as cli

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        if cli(["run", str(HERE.parent / "data" / "tiny_scenario.yaml"), "--out", str(out), "--no-progress"]) != 0:
            return 1
        with open(out / "metrics.csv", newline="") as f:
            rows = list(csv.DictReader(f))
    per_pilot = {}
    for r in rows:
        per_pilot[r["method"]] = {c: (r[c] if c in ("outcome", "success", "collision") else round(float(r[c]), 4))
                                  for c in COLUMNS}
    data = {"scenario": "tests/data/tiny_scenario.yaml", "tolerances": TOLERANCES, "methods": per_pilot}
    (HERE / "tiny_metrics.json").write_text(json.dumps(data, indent=2) + "\n")
    print(json.dumps(data, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
