"""`uam-compare demo`, a quick flight-model check: it flies both presets and reports the flight."""
from __future__ import annotations

import re

from compare.cli import main


def test_demo_flies_both_presets_to_every_waypoint(capsys):
    assert main(["demo", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    for preset in ("small_quad", "uam_multicopter"):
        assert preset in out
    reached = re.findall(r"reached (\d+)/(\d+) waypoints", out)
    assert len(reached) == 2 and all(a == b for a, b in reached), out
    ended = re.findall(r"ended at \((-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\) m", out)
    for x, y, z in ended:
        assert abs(float(x)) < 0.6 and abs(float(y)) < 0.6 and abs(float(z) - 20.0) < 0.6
    energy = [float(e) for e in re.findall(r"rotor shaft energy ([\d.]+) kJ", out)]
    assert energy[0] < energy[1]   # the 900 kg multicopter uses far more energy than the 1.5 kg quad


def test_demo_is_deterministic(capsys):
    main(["demo", "small_quad", "--seed", "3"])
    first = capsys.readouterr().out
    main(["demo", "small_quad", "--seed", "3"])
    second = capsys.readouterr().out
    strip = lambda s: re.sub(r"simulated \d+x", "", s)  # noqa: E731 (wall-clock speed differs)
    assert strip(first) == strip(second)


def test_bad_vehicle_is_a_clear_error(capsys):
    assert main(["demo", "no_such_vehicle"]) == 2
    err = capsys.readouterr().err
    assert "no_such_vehicle: vehicle: no such file and not a preset" in err
