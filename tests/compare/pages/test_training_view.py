"""`uam-compare view-training`: the page of a policy's training, from Python and in headless Chromium."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_viewer import CHROMIUM_FLAGS, _chromium

from compare.cli import main
from compare.pages.training_view import build_training_view, training_payload
from uam_fdm.files.npz import write_npz


@pytest.fixture(scope="module")
def page(tiny_flights_policy, tmp_path_factory) -> Path:
    return build_training_view(tiny_flights_policy, tmp_path_factory.mktemp("tv") / "training.html")


def _data(html_path: Path) -> dict:
    m = re.search(r'<script type="application/json" id="uam-data">(.*?)</script>',
                  html_path.read_text(encoding="utf-8"), re.DOTALL)
    assert m, "no data block"
    return json.loads(m.group(1))


def test_page_holds_curves_checkpoints_and_tasks(page, tiny_flights_policy):
    data = _data(page)
    assert [c["timesteps"] for c in data["checkpoints"]] == [0, 512, 1024]
    assert len(data["tasks"]) == 4 and all(len(c["flights"]) == 4 for c in data["checkpoints"])
    assert data["curve"]["kept"] == 1024 and data["curve"]["timesteps"][-1] == 1024
    f = data["checkpoints"][0]["flights"][0]
    assert len(f["x"]) == len(f["speed"]) == len(f["clearance"]) and f["color"] and f["words"]
    assert data["dt_s"] == pytest.approx(0.1)
    assert data["tasks"][0]["figure"]["data"][0]["type"] == "mesh3d"
    text = page.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and "{{" not in text.split("<script")[0]
    assert not re.search(r"<script[^>]*\bsrc=", text), "scripts must be inline"
    assert not re.search(r"<link[^>]*\bhref=", text), "no external style sheets"


def test_same_folder_gives_same_page(tiny_flights_policy, tmp_path):
    a = build_training_view(tiny_flights_policy, tmp_path / "a.html").read_bytes()
    assert a == build_training_view(tiny_flights_policy, tmp_path / "b.html").read_bytes()


def test_policy_texts_cannot_break_the_page(tiny_flights_policy, tmp_path):
    hostile = tmp_path / "</script><script>alert(1)</script>"
    shutil.copytree(tiny_flights_policy, hostile)
    tasks = hostile / "training_flights" / "tasks.json"
    d = json.loads(tasks.read_text())
    d["rule"] = "</script><img src=x onerror=alert(1)>"
    tasks.write_text(json.dumps(d))
    html = build_training_view(hostile, tmp_path / "h.html").read_text(encoding="utf-8")
    # the page's own four scripts (plotly.js, the data, player.js, training.js) and no other
    assert html.count("</script>") == 4 and "<img src=x" not in html
    assert _data(tmp_path / "h.html")["policy"]["rule"] == d["rule"]


def test_view_training_command(tiny_flights_policy, tmp_path, capsys, monkeypatch):
    out = tmp_path / "page.html"
    assert main(["view-training", str(tiny_flights_policy), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out) and out.stat().st_size > 1_000_000
    assert main(["view-training", str(tiny_flights_policy), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "the file exists" in err and "--overwrite" in err
    assert main(["view-training", str(tiny_flights_policy), "--out", str(out), "--overwrite"]) == 0
    monkeypatch.chdir(tmp_path)  # the default file: <folder name>-training.html here, never replaced unasked
    assert main(["view-training", str(tiny_flights_policy)]) == 0
    assert (tmp_path / f"{tiny_flights_policy.name}-training.html").is_file()
    capsys.readouterr()
    assert main(["view-training", str(tiny_flights_policy)]) == 2
    assert "the file exists" in capsys.readouterr().err


@pytest.mark.parametrize("vehicle", ["small_quad", "uam_multicopter"])
def test_both_shipped_policies_carry_their_training_flights(vehicle):
    """A fresh install opens the learning of either shipped policy: its folder holds the flights of every
    checkpoint of its final training run (from step 0), the kept one among them."""
    from rl.policies.folder import SHIPPED_POLICIES

    data = training_payload(SHIPPED_POLICIES[vehicle])
    steps = [c["timesteps"] for c in data["checkpoints"]]
    assert len(steps) >= 10 and steps[0] == 0 and steps == sorted(steps)
    assert data["policy"]["vehicle"] == vehicle and len(data["tasks"]) >= 8
    assert data["curve"]["kept"] in steps  # the kept checkpoint's flights are among them
    assert all(len(c["flights"]) == len(data["tasks"]) for c in data["checkpoints"])


def test_a_folder_without_flights_is_one_clear_line(tmp_path, capsys):
    from rl.policies.folder import DEFAULT_POLICY_DIR

    bare = tmp_path / "bare"  # a policy trained before recording (or with --record-flights 0)
    shutil.copytree(DEFAULT_POLICY_DIR, bare, ignore=shutil.ignore_patterns("training_flights"))
    assert main(["view-training", str(bare), "--out", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(bare) in err and "uam-compare train" in err
    assert not (tmp_path / "x.html").exists()
    assert main(["view-training", str(tmp_path / "nowhere")]) == 2
    assert "not a policy folder" in capsys.readouterr().err


def test_a_malformed_checkpoint_is_named(tiny_flights_policy, tmp_path):
    bad = tmp_path / "pol"
    shutil.copytree(tiny_flights_policy, bad)
    write_npz(bad / "training_flights" / "step_00000000512.npz", {"timesteps": np.array(512)})
    with pytest.raises(ValueError, match=r"step_00000000512.npz: array 'task' is missing"):
        training_payload(bad)


# ---- in headless Chromium ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def browser_page(page):
    import os

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
        pg = browser.new_page(viewport={"width": 1300, "height": 900})
        log: dict[str, list[str]] = {"errors": [], "requests": []}
        pg.on("console", lambda m: log["errors"].append(m.text) if m.type == "error" else None)
        pg.on("pageerror", lambda e: log["errors"].append(f"uncaught: {e}"))
        pg.on("request", lambda r: None if r.url.startswith(("file:", "data:", "blob:"))
              else log["requests"].append(r.url))
        pg.goto(page.as_uri())
        pg.wait_for_function("document.body.dataset.ready === '1'", timeout=60_000)
        yield pg, log
        browser.close()


def _shot(pg, selector: str) -> np.ndarray:
    import io

    from PIL import Image

    png = pg.screenshot(clip=pg.locator(selector).bounding_box())
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def test_renders_without_errors_or_network(browser_page):
    pg, log = browser_page
    assert pg.evaluate("window.uamTraining.state().ready")
    assert log["errors"] == [] and log["requests"] == []
    for sel in ("#plot-a", "#plot-b", "#curve"):
        img = _shot(pg, sel)
        assert (np.abs(img - img[0, 0]).max(axis=-1) > 30).mean() > 0.02, f"{sel} is blank"
    assert pg.locator("#tasks .task").count() == 4
    assert "1.0 k timesteps" in pg.inner_text("#ckpt-label")


def test_scrubber_changes_the_drawn_flights(browser_page):
    pg, log = browser_page
    pg.evaluate("window.uamTraining.setIndex(1e9)")  # the whole trail
    pg.wait_for_timeout(300)
    last = pg.evaluate("window.uamTraining.drawn(0)")
    pg.evaluate("(() => { const s = document.getElementById('ckpt'); s.value = '0';"
                " s.dispatchEvent(new Event('input')); })()")  # the scrubber, driven as a user would
    pg.wait_for_function("window.uamTraining.state().a === 0")
    pg.wait_for_timeout(500)
    first = pg.evaluate("window.uamTraining.drawn(0)")
    assert first != last
    data = pg.evaluate("window.uamTraining.data.checkpoints[0].flights[0].x")
    assert first["x"] == data
    assert "0 timesteps" in pg.inner_text("#ckpt-label")
    assert log["errors"] == []


def test_two_checkpoints_side_by_side_on_the_same_task(browser_page):
    pg, log = browser_page
    pg.select_option("#ckpt-b", "2")
    pg.wait_for_function("window.uamTraining.state().b === 2")
    pg.click("#tasks .task[data-task='1']")
    pg.wait_for_function("window.uamTraining.state().task === 1")
    pg.wait_for_timeout(500)
    a, b = pg.evaluate("[window.uamTraining.drawn(0), window.uamTraining.drawn(1)]")
    want = pg.evaluate("[0, 2].map((c) => window.uamTraining.data.checkpoints[c].flights[1].x)")
    assert a["x"] == want[0] and b["x"] == want[1]
    assert log["errors"] == []


def test_hovering_the_curve_selects_a_checkpoint(browser_page):
    pg, log = browser_page
    pg.evaluate("window.uamTraining.selectCheckpoint(0)")
    pg.wait_for_function("window.uamTraining.state().a === 0")
    # the mouse over the last checkpoint's marker (trace 2, point 2; its place from plotly's own axes)
    x, y = pg.evaluate("""(() => { const gd = document.getElementById('curve'), L = gd._fullLayout;
        const tr = gd.data[2], r = gd.getBoundingClientRect();
        return [r.left + L._size.l + L.xaxis.l2p(tr.x[2]), r.top + L._size.t + L.yaxis2.l2p(tr.y[2])]; })()""")
    pg.mouse.move(x - 30, y - 30)
    pg.mouse.move(x, y, steps=5)
    pg.wait_for_function("window.uamTraining.state().a === 2", timeout=5_000)
    assert log["errors"] == []


def test_play_moves_the_vehicles(browser_page):
    pg, log = browser_page
    pg.evaluate("window.uamTraining.setIndex(0)")
    pg.click("#play")
    pg.wait_for_timeout(800)
    s = pg.evaluate("window.uamTraining.state()")
    assert s["playing"] and s["index"] > 0
    pg.click("#play")
    assert not pg.evaluate("window.uamTraining.state().playing")
    assert log["errors"] == []


def test_the_toolbar_never_covers_the_legend_and_the_success_axis_reads_round(browser_page):
    """At any width the legend stands under the axes, clear of plotly's toolbar (shown here by hovering) and of the
    plot; the success axis has ticks of its own at round quarters (not synced to the return axis)."""
    pg, log = browser_page
    rects = """(() => { const gd = document.getElementById('curve'), L = gd._fullLayout, r = gd.getBoundingClientRect();
        const box = (e) => { const b = e.getBoundingClientRect(); return [b.left, b.top, b.right, b.bottom]; };
        return {legend: box(gd.querySelector('.legend')), buttons: [...gd.querySelectorAll('.modebar-btn')].map(box),
                plot: [r.left + L._size.l, r.top + L._size.t, r.left + L._size.l + L._size.w,
                       r.top + L._size.t + L._size.h], div: box(gd)}; })()"""

    def apart(a, b):
        return a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]

    try:
        for width in (1300, 900, 700):
            pg.set_viewport_size({"width": width, "height": 900})
            pg.wait_for_timeout(400)  # the plot follows its box (responsive)
            box = pg.locator("#curve").bounding_box()
            pg.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 3)
            pg.wait_for_timeout(300)
            r = pg.evaluate(rects)
            assert r["buttons"] and all(apart(r["legend"], b) for b in r["buttons"]), (width, r)
            assert r["legend"][1] >= r["plot"][3] and r["legend"][3] <= r["div"][3] + 1, (width, r)
        ticks = pg.evaluate("[...document.querySelectorAll('#curve .y2tick text')].map((t) => t.textContent)")
        assert ticks == ["0%", "25%", "50%", "75%", "100%"]
    finally:
        pg.set_viewport_size({"width": 1300, "height": 900})
    assert log["errors"] == []
