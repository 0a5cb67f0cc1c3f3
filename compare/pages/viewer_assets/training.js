/* uam-compare: watching a policy learn. Curves, a scrubber over the recorded checkpoints, and one fixed task
 * flown by two checkpoints side by side in 3D, playable in time.
 *
 * The page's data (script#uam-data): curve (timesteps, training return, validation success, kept), tasks
 * (per fixed task: its plotly figure with traces 0 city, 1 start, 2 goal), checkpoints (per recorded
 * checkpoint: per task its flight sampled every dt_s seconds: x, y, z, speed, clearance, outcome, colour).
 * window.uamTraining exposes the state for tests and for scripting from the console.
 */
(function () {
  "use strict";

  const DATA = JSON.parse(document.getElementById("uam-data").textContent);
  const CK = DATA.checkpoints;
  const curveDiv = document.getElementById("curve");
  const plots = [document.getElementById("plot-a"), document.getElementById("plot-b")];
  const heads = [document.getElementById("head-a"), document.getElementById("head-b")];
  const ckptSlider = document.getElementById("ckpt");
  const ckptLabel = document.getElementById("ckpt-label");
  const ckptB = document.getElementById("ckpt-b");
  const tasksBox = document.getElementById("tasks");
  const timeSlider = document.getElementById("time");
  const clock = document.getElementById("clock");
  const playButton = document.getElementById("play");
  const rateSelect = document.getElementById("rate");
  const CONFIG = { responsive: true, displaylogo: false, scrollZoom: true };
  const PATH = 3; // first flight trace: path, trail, vehicle

  const state = { a: CK.length - 1, b: 0, task: 0, index: 0, ready: false };
  let queue = Promise.resolve(); // drawing requests run one after the other

  function later(fn) { queue = queue.then(fn, fn); return queue; }
  function fmt(v, d) { return (v === null || v === undefined || !isFinite(v)) ? "\u2013" : Number(v).toFixed(d); }
  function esc(text) {
    return String(text).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;",
                                                      '"': "&quot;", "'": "&#39;" }[c]));
  }
  function steps(n) { return n >= 1e6 ? `${(n / 1e6).toFixed(2)} M` : n >= 1e3 ? `${(n / 1e3).toFixed(1)} k` : `${n}`; }
  function flight(c, k) { return CK[c].flights[k !== undefined ? k : state.task]; }
  function length() { return Math.max(flight(state.a).x.length, flight(state.b).x.length); }

  /* ---- curves ---------------------------------------------------------------------------------------- */
  function curveShapes() {
    const line = (x, color, dash, width) => ({ type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0, y1: 1,
                                               line: { color: color, dash: dash, width: width } });
    const shapes = [line(CK[state.a].timesteps, "#222", "solid", 2), line(CK[state.b].timesteps, "#888", "dot", 2)];
    if (DATA.curve.kept !== null) shapes.push(line(DATA.curve.kept, "#2ca02c", "dash", 1.5));
    return shapes;
  }

  function drawCurve() {
    const c = DATA.curve;
    const n = CK.length ? CK[0].flights.length : 0;
    const traces = [
      { x: c.timesteps, y: c.train_return, name: "training return", mode: "lines", line: { color: "#1f77b4" },
        hovertemplate: "%{x:,} steps<br>return %{y:.1f}<extra></extra>" },
      { x: c.timesteps, y: c.val_success, name: "validation success", mode: "lines+markers", yaxis: "y2",
        connectgaps: true, line: { color: "#2ca02c" }, marker: { size: 6 },
        hovertemplate: "%{x:,} steps<br>validation success %{y:.0%}<extra></extra>" },
      { x: CK.map((k) => k.timesteps), y: CK.map((k) => (n ? k.successes / n : 0)), name: `fixed tasks arrived (of ${n})`,
        mode: "markers", yaxis: "y2", marker: { size: 11, symbol: "diamond", color: "#444" },
        hovertemplate: "checkpoint %{x:,} steps<br>%{customdata} fixed tasks arrived<extra></extra>",
        customdata: CK.map((k) => `${k.successes} of ${n}`) },
    ];
    const annotations = DATA.curve.kept === null ? [] : [{ x: DATA.curve.kept, y: 1, yref: "paper", text: "kept",
      showarrow: false, font: { color: "#2ca02c" }, xanchor: "left", yanchor: "top" }];
    // the legend under the axes (plotly widens the margin for it) and the toolbar above them, so neither covers
    // the other or the curves, whatever the width; the success axis at round quarters of its own (plotly would
    // otherwise sync an overlaying axis to the left axis's ticks)
    const layout = { margin: { l: 55, r: 55, t: 28, b: 40 }, hovermode: "closest", showlegend: true,
                     legend: { orientation: "h", x: 0, xanchor: "left", y: -0.28, yanchor: "top", font: { size: 11 } },
                     xaxis: { title: { text: "timesteps", standoff: 4 } }, yaxis: { title: { text: "training return" } },
                     yaxis2: { title: { text: "success" }, overlaying: "y", side: "right", range: [0, 1.05],
                               tickmode: "array", tickvals: [0, 0.25, 0.5, 0.75, 1], tickformat: ".0%",
                               showgrid: false },
                     shapes: curveShapes(), annotations: annotations };
    return Plotly.newPlot(curveDiv, traces, layout, { displaylogo: false, responsive: true }).then(() => {
      curveDiv.on("plotly_hover", (ev) => {
        if (!ev.points || !ev.points.length) return;
        selectCheckpoint(nearestCheckpoint(ev.points[0].x));
      });
    });
  }

  function nearestCheckpoint(x) {
    let best = 0;
    CK.forEach((k, i) => { if (Math.abs(k.timesteps - x) < Math.abs(CK[best].timesteps - x)) best = i; });
    return best;
  }

  /* ---- the selected checkpoint's tasks ---------------------------------------------------------------- */
  function drawTasks() {
    ckptLabel.textContent = `${steps(CK[state.a].timesteps)} timesteps \u00b7 ${CK[state.a].successes} of ` +
      `${CK[state.a].flights.length} fixed tasks arrived` +
      (CK[state.a].timesteps === DATA.curve.kept ? " \u00b7 the kept checkpoint" : "");
    tasksBox.innerHTML = CK[state.a].flights.map((f, k) => {
      const t = DATA.tasks[k];
      return `<div class="task${k === state.task ? " chosen" : ""}" data-task="${k}"
        style="border-left-color:${esc(f.color)}">#${k} ${esc(t.leg)} ${fmt(t.distance_m, 0)} m, ${esc(t.turbulence)}<br>
        <span class="o ${esc(f.outcome)}">${esc(f.words)}</span> ${fmt(f.time_s, 1)} s,
        min clear ${fmt(f.min_clearance_m, 1)} m</div>`;
    }).join("");
    tasksBox.querySelectorAll(".task").forEach((el) => el.addEventListener("click",
      () => selectTask(Number(el.dataset.task))));
  }

  function headText(c) {
    const f = flight(c);
    return `${steps(CK[c].timesteps)} steps: <span class="o ${esc(f.outcome)}">${esc(f.words)}</span> after ` +
      `${fmt(f.time_s, 1)} s, min clearance ${fmt(f.min_clearance_m, 2)} m`;
  }

  /* ---- 3D ----------------------------------------------------------------------------------------------- */
  function flightTraces(c) {
    const f = flight(c);
    const hover = "t %{customdata[0]:.1f} s<br>speed %{customdata[1]:.1f} m/s<br>clearance %{customdata[2]:.1f} m" +
      "<extra></extra>";
    const cd = f.x.map((_, j) => [j * DATA.dt_s, f.speed[j], f.clearance[j]]);
    return [
      { type: "scatter3d", mode: "lines", x: f.x, y: f.y, z: f.z, line: { color: f.color, width: 3 }, opacity: 0.45,
        customdata: cd, hovertemplate: hover, name: "path" },
      { type: "scatter3d", mode: "lines", x: f.x.slice(0, 1), y: f.y.slice(0, 1), z: f.z.slice(0, 1),
        line: { color: f.color, width: 8 }, customdata: cd.slice(0, 1), hovertemplate: hover, name: "trail" },
      { type: "scatter3d", mode: "markers", x: f.x.slice(0, 1), y: f.y.slice(0, 1), z: f.z.slice(0, 1),
        marker: { size: 6, color: f.color, line: { color: "black", width: 2 } }, customdata: cd.slice(0, 1),
        hovertemplate: hover, name: "vehicle" },
    ];
  }

  function drawSide(s) {
    const c = s === 0 ? state.a : state.b;
    const fig = DATA.tasks[state.task].figure;
    heads[s].innerHTML = (s === 0 ? "selected: " : "") + headText(c);
    return Plotly.react(plots[s], fig.data.concat(flightTraces(c)), fig.layout, CONFIG);
  }

  function drawTime() {
    const k = state.index;
    clock.textContent = `t = ${fmt(k * DATA.dt_s, 1)} s`;
    return Promise.all([state.a, state.b].map((c, s) => {
      const f = flight(c);
      const j = Math.min(k, f.x.length - 1);
      const cd = [];
      for (let i = 0; i <= j; i++) cd.push([i * DATA.dt_s, f.speed[i], f.clearance[i]]);
      return Plotly.restyle(plots[s], {
        x: [f.x.slice(0, j + 1), [f.x[j]]], y: [f.y.slice(0, j + 1), [f.y[j]]], z: [f.z.slice(0, j + 1), [f.z[j]]],
        customdata: [cd, [cd[j]]] }, [PATH + 1, PATH + 2]);
    }));
  }

  function resetTime() {
    timeSlider.max = String(length() - 1);
    state.index = Math.min(state.index, length() - 1);
    timeSlider.value = String(state.index);
  }

  /* ---- selections --------------------------------------------------------------------------------------- */
  function selectCheckpoint(i) {
    i = Math.max(0, Math.min(CK.length - 1, Math.round(i)));
    if (i === state.a && state.ready) return queue;
    state.a = i;
    ckptSlider.value = String(i);
    drawTasks();
    resetTime();
    return later(() => Promise.all([drawSide(0), Plotly.relayout(curveDiv, { shapes: curveShapes() })])
      .then(drawTime));
  }

  function compareWith(i) {
    state.b = Math.max(0, Math.min(CK.length - 1, Math.round(i)));
    ckptB.value = String(state.b);
    resetTime();
    return later(() => Promise.all([drawSide(1), Plotly.relayout(curveDiv, { shapes: curveShapes() })])
      .then(drawTime));
  }

  function selectTask(k) {
    state.task = k;
    drawTasks();
    resetTime();
    return later(() => Promise.all([drawSide(0), drawSide(1)]).then(drawTime));
  }

  function setIndex(k) {
    state.index = Math.max(0, Math.min(length() - 1, Math.round(k)));
    timeSlider.value = String(state.index);
    return later(drawTime);
  }

  /* ---- playing (player.js) ------------------------------------------------------------------------------ */
  const player = window.uamPlayer({
    button: playButton, rate: rateSelect, now: () => state.index * DATA.dt_s, end: () => (length() - 1) * DATA.dt_s,
    show: (t) => setIndex(t / DATA.dt_s),
  });
  const stop = player.stop;

  /* ---- start -------------------------------------------------------------------------------------------- */
  const pol = DATA.policy;
  document.getElementById("title").textContent = `Watching ${pol.folder} learn (${pol.vehicle})`;
  document.getElementById("about").textContent = `Fixed tasks: ${pol.rule}.`;
  ckptSlider.max = String(CK.length - 1);
  CK.forEach((k, i) => {
    const opt = document.createElement("option");
    opt.value = String(i);
    opt.textContent = `${steps(k.timesteps)} steps (${k.successes} arrived)`;
    ckptB.appendChild(opt);
  });
  state.b = 0;
  ckptB.value = "0";
  ckptSlider.value = String(state.a);
  ckptSlider.addEventListener("input", () => selectCheckpoint(Number(ckptSlider.value)));
  ckptB.addEventListener("change", () => compareWith(Number(ckptB.value)));
  timeSlider.addEventListener("input", () => { stop(); setIndex(Number(timeSlider.value)); });

  window.uamTraining = {
    data: DATA,
    selectCheckpoint: selectCheckpoint,
    compareWith: compareWith,
    selectTask: selectTask,
    setIndex: (k) => { stop(); return setIndex(k); },
    play: player.play,
    stop: stop,
    state: () => ({ a: state.a, b: state.b, task: state.task, index: state.index, playing: player.playing(),
                    ready: state.ready, timesteps_a: CK[state.a].timesteps, timesteps_b: CK[state.b].timesteps }),
    drawn: (s) => { const d = plots[s].data[PATH]; return { x: Array.from(d.x), y: Array.from(d.y) }; },
  };
  drawTasks();
  resetTime();
  window.uamTraining.loaded = drawCurve()
    .then(() => later(() => Promise.all([drawSide(0), drawSide(1)]).then(drawTime)))
    .then(() => { state.ready = true; document.body.dataset.ready = "1"; });
})();
