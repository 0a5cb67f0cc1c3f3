"""The HTML viewer: content and self-containment from Python, then the page in a real headless Chromium.

Browser tests drive Debian's Chromium through Playwright (the pip package; its own browser download is
never used) and skip with the reason when either is missing. `.ci/run` installs Chromium.
"""
from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from compare.cli import main
from compare.pages.viewer import VIEWER_NAME, ViewerConfig, build_viewer, building_mesh, group_payload
from compare.playback.flights import flight_groups
from synthetic_run import LABELS, SCENARIO, toy_map, write_run

ORANGE, BLUE = (255, 127, 14), (31, 119, 180)  # tab:orange (PPO), tab:blue (RRT* + MPC)
# Flags for a root user on a machine with a closed network and no GPU: WebGL through SwiftShader.
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-quic", "--no-first-run"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("viewer") / "run"
    write_run(out, None)
    return out


@pytest.fixture(scope="module")
def page_html(run_dir) -> Path:
    return build_viewer(run_dir)


def _data(html_path: Path) -> dict:
    text = html_path.read_text(encoding="utf-8")
    m = re.search(r'<script type="application/json" id="uam-data">(.*?)</script>', text, re.DOTALL)
    assert m, "no data block"
    return json.loads(m.group(1))


def _array(v) -> np.ndarray:
    """A figure array as plotly JSON holds it: a list, or a base64 typed array {dtype, bdata, shape}."""
    if isinstance(v, dict) and "bdata" in v:
        a = np.frombuffer(base64.b64decode(v["bdata"]), dtype=np.dtype(v["dtype"]))
        return a.reshape([int(n) for n in str(v.get("shape", len(a))).split(",")])
    return np.asarray(v)


# ---- without a browser -----------------------------------------------------------------------------------
def test_page_is_self_contained(page_html, run_dir):
    assert page_html == run_dir / VIEWER_NAME
    text = page_html.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    assert not re.search(r"<script[^>]*\bsrc=", text), "scripts must be inline"
    assert not re.search(r"<link[^>]*\bhref=", text), "no external style sheets"
    assert "{{" not in text.split("<script")[0], "template placeholder left"
    assert "plotly.js" in text and "window.uamViewer" in text
    assert [p.name for p in run_dir.iterdir() if p.name.startswith(".")] == []  # atomic write, no temp file


def test_page_data_holds_every_flight(page_html):
    data = _data(page_html)
    assert [g["spec"] for g in data["groups"]] == [f"{SCENARIO}:0:0", f"{SCENARIO}:1:0"]
    g1 = data["groups"][1]
    assert [p["label"] for p in g1["pilots"]] == [LABELS["ppo"], LABELS["rrt_mpc"]]
    ppo = g1["pilots"][0]
    assert ppo["outcome"] == "collision" and ppo["end_t_s"] == pytest.approx(12.0)
    assert g1["duration_s"] == pytest.approx(24.0)
    t = np.array(g1["t"])
    assert t[0] == 0.0 and np.all(np.diff(t) > 0) and len(t) <= ViewerConfig().max_samples + 1
    for p in g1["pilots"]:
        assert len(p["x"]) == len(p["speed"]) == len(p["clearance"]) == len(t)
    # PPO stopped at 12 s: held in place afterwards, and its path trace ends there
    assert ppo["x"][-1] == ppo["x"][ppo["last"]] and t[ppo["last"] - 1] <= 12.0 + 1e-9
    names = [tr.get("name") for tr in g1["figure"]["data"]]
    assert names[:3] == ["buildings", "start", "goal"]
    assert names[3:] == [f"{LABELS['ppo']} path", LABELS["ppo"], f"{LABELS['ppo']} vehicle",
                         f"{LABELS['rrt_mpc']} path", LABELS["rrt_mpc"], f"{LABELS['rrt_mpc']} vehicle"]
    for tr in g1["figure"]["data"][3:]:
        for word in ("t %{customdata[0]", "speed", "clearance"):
            assert word in tr["hovertemplate"]


def test_building_mesh_is_closed_and_complete():
    bmap = toy_map()
    mesh = building_mesh(bmap)
    n_tri = sum((len(b.footprint_xy_m()) - 2) + 2 * len(b.footprint_xy_m()) for b in bmap.buildings)
    assert len(mesh.i) == n_tri
    # Every edge of roof + walls is shared by exactly two triangles except the ground outline (open bottom).
    edges = Counter()
    for tri in zip(mesh.i, mesh.j, mesh.k):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edges[frozenset((a, b))] += 1
    z = np.asarray(mesh.z)
    for edge, count in edges.items():
        on_ground = all(z[v] == 0.0 for v in edge)
        assert count == (1 if on_ground else 2), (sorted(edge), count)
    heights = {b.height_m for b in bmap.buildings}
    assert set(np.round(np.asarray(mesh.z), 2)) == {0.0} | {round(h, 2) for h in heights}


def test_group_crop_keeps_only_nearby_buildings(run_dir):
    g = flight_groups(run_dir)[0]
    payload = group_payload(g, ViewerConfig(max_samples=50))
    assert len(payload["t"]) <= 51
    ids = {int(c[0]) for c in _array(payload["figure"]["data"][0]["customdata"])}
    assert ids and ids <= {b.id for b in toy_map().buildings}


def test_view_command(run_dir, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert main(["view", str(run_dir), "--out", str(out)]) == 0
    assert out.is_file() and str(out) in capsys.readouterr().out
    assert main(["view", str(tmp_path / "missing")]) == 2
    assert "not a run folder" in capsys.readouterr().err


def test_same_run_gives_same_page(run_dir, tmp_path):
    a = build_viewer(run_dir, tmp_path / "a.html").read_bytes()
    b = build_viewer(run_dir, tmp_path / "b.html").read_bytes()
    assert a == b


# ---- in headless Chromium ------------------------------------------------------------------------------
def _chromium() -> tuple[str | None, str]:
    """The browser to drive and, when there is none, why."""
    env = os.environ.get("UAM_CHROMIUM")
    if env:
        return (env, "") if os.access(env, os.X_OK) else (None, f"UAM_CHROMIUM={env} is not an executable")
    exe = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
    return exe, "" if exe else "no Chromium installed (apt-get install chromium, or set UAM_CHROMIUM)"


@pytest.fixture(scope="module")
def browser_page(page_html):
    # CI sets UAM_REQUIRE_BROWSER=1 after installing Chromium, so a broken install fails instead of skipping
    missing = pytest.fail if os.environ.get("UAM_REQUIRE_BROWSER") == "1" else pytest.skip
    exe, why = _chromium()
    if exe is None:
        missing(f"{why}: browser tests skipped")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        missing("the playwright package is not installed (pip install -e '.[test]'): browser tests skipped")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_FLAGS, headless=True)
        page = browser.new_page(viewport={"width": 1200, "height": 800})
        log: dict[str, list[str]] = {"errors": [], "requests": []}
        page.on("console", lambda m: log["errors"].append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: log["errors"].append(f"uncaught: {e}"))
        page.on("request", lambda r: None if r.url.startswith(("file:", "data:", "blob:"))
                else log["requests"].append(r.url))
        page.goto(page_html.as_uri())
        page.wait_for_function("document.body.dataset.ready === '1'", timeout=60_000)
        yield page, log
        browser.close()


def _shot(page) -> np.ndarray:
    from PIL import Image

    box = page.locator("#plot").bounding_box()
    png = page.screenshot(clip=box)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _near(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 40) -> np.ndarray:
    return np.all(np.abs(img - np.array(rgb)) <= tol, axis=-1)


def test_loads_without_errors_or_network(browser_page):
    page, log = browser_page
    assert page.evaluate("window.uamViewer.state().ready")
    assert page.evaluate("!!document.querySelector('#plot .gl-container canvas, #plot canvas')"), "no WebGL canvas"
    assert log["errors"] == []
    assert log["requests"] == []
    assert "toy-quad #0" in page.inner_text("#flight")


def test_screenshot_shows_buildings_and_paths(browser_page):
    page, log = browser_page
    page.evaluate("window.uamViewer.setTime(1e9)")  # the end: trails drawn in full
    page.wait_for_timeout(300)
    full = _shot(page)
    assert _near(full, ORANGE).sum() > 150, "PPO path (orange) not visible"
    assert _near(full, BLUE).sum() > 150, "RRT* + MPC path (blue) not visible"
    page.evaluate("Plotly.restyle('plot', {visible: false}, [0])")
    page.wait_for_timeout(300)
    no_buildings = _shot(page)
    page.evaluate("Plotly.restyle('plot', {visible: true}, [0])")
    page.wait_for_timeout(300)
    changed = np.any(np.abs(full - no_buildings) > 30, axis=-1)
    assert changed.mean() > 0.015, f"buildings cover only {changed.mean():.1%} of the plot"
    # where buildings were drawn the pixels are the height colour scale (green-teal-yellow), not paper white
    px = full[changed]
    greenish = (px[:, 1] > px[:, 2]) & (px[:, 1] > 60)
    assert greenish.mean() > 0.5
    assert log["errors"] == []


def test_slider_and_play_move_the_vehicles(browser_page):
    page, log = browser_page
    page.select_option("#flight", "1")  # PPO collides at 12 s, RRT* + MPC arrives at 24 s
    page.wait_for_function("window.uamViewer.state().group === 1")
    s0 = page.evaluate("window.uamViewer.state()")
    assert s0["index"] == 0 and [p["status"] for p in s0["pilots"]] == ["flying", "flying"]
    before = _shot(page)
    page.fill("#time", "0")  # the range input, driven as a user would: set and fire input
    page.evaluate("(() => { const s = document.getElementById('time'); s.value = String(Math.floor(s.max * 0.8));"
                  " s.dispatchEvent(new Event('input')); })()")
    page.wait_for_timeout(300)
    s1 = page.evaluate("window.uamViewer.state()")
    assert s1["t"] == pytest.approx(0.8 * 24.0, abs=0.1)
    assert s1["pilots"][0]["status"] == "collided at 12.0 s" and s1["pilots"][1]["status"] == "flying"
    assert s1["pilots"][1]["x"] != s0["pilots"][1]["x"]
    assert page.inner_text("#clock").startswith("t = 19.")
    assert np.any(np.abs(_shot(page) - before) > 30, axis=-1).sum() > 50  # the vehicles moved on screen
    page.evaluate("window.uamViewer.setTime(0)")
    page.click("#play")
    page.wait_for_timeout(800)
    s2 = page.evaluate("window.uamViewer.state()")
    assert s2["playing"] and s2["index"] > 0
    page.click("#play")
    assert not page.evaluate("window.uamViewer.state().playing")
    assert log["errors"] == []


def test_hover_reads_out_time_speed_and_clearance(browser_page):
    page, log = browser_page
    page.select_option("#flight", "0")
    page.wait_for_function("window.uamViewer.state().group === 0")
    page.evaluate("window.uamViewer.setTime(1e9)")
    page.wait_for_timeout(300)
    img = _shot(page)
    box = page.locator("#plot").bounding_box()
    ys, xs = np.nonzero(_near(img, ORANGE, 25))
    assert len(xs), "no orange path pixels to hover"
    texts = []
    for k in np.linspace(0, len(xs) - 1, 8).astype(int):  # a few points along the path: a line is thin
        page.mouse.move(box["x"] + float(xs[k]), box["y"] + float(ys[k]))
        page.wait_for_timeout(150)
        texts.append(page.evaluate("Array.from(document.querySelectorAll('.hovertext')).map(e => e.textContent)"
                                   ".join(' ')"))
        if "clearance" in texts[-1]:
            break
    hit = next((t for t in texts if "clearance" in t), None)
    assert hit is not None, texts
    assert LABELS["ppo"] in hit and re.search(r"t \d+\.\d\d s", hit) and "m/s" in hit
    assert log["errors"] == []
