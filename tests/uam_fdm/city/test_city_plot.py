"""City figures: Figure API only, drawing into given Axes, atomic PNG output."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from matplotlib.figure import Figure

from uam_fdm.city.mapfile import load_named_map
from uam_fdm.city.plot import draw_map_3d, draw_map_topdown, map_figure, render_named_maps, save_figure


def test_draw_into_given_axes() -> None:
    bmap = load_named_map("canyon")
    fig = Figure()
    ax = fig.add_subplot(1, 2, 1)
    coll = draw_map_topdown(ax, bmap)
    assert len(coll.get_paths()) == len(bmap.buildings)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    faces = draw_map_3d(ax3, bmap)
    assert len(faces.get_facecolor()) == 5 * len(bmap.buildings)  # roof + 4 walls per box
    assert ax.get_xlim()[1] >= bmap.bounds_max_m[0]


def test_render_named_maps_writes_pngs(tmp_path: Path) -> None:
    paths = render_named_maps(tmp_path)
    assert [p.name for p in paths] == ["map_canyon.png", "map_downtown.png", "map_suburb.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 20_000
    assert sorted(x.name for x in tmp_path.iterdir()) == [p.name for p in paths]  # no temp files left
    save_figure(map_figure(load_named_map("suburb"), title="again"), paths[-1])  # overwrite in place
    assert sorted(x.name for x in tmp_path.iterdir()) == [p.name for p in paths]


def test_cli_and_no_pyplot(tmp_path: Path) -> None:
    code = ("import sys, uam_fdm.city.plot as m; "
            "assert m.main([sys.argv[1]]) == 0; "
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot was imported'")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert len(list(tmp_path.glob("map_*.png"))) == 3
