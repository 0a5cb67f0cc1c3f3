/* uam-compare viewer: switches between the run's flights and moves the vehicles along the time grid.
 *
 * The page's data (script#uam-data) holds, per comparison cell, a plotly figure built in Python
 * (traces: 0 buildings, 1 start, 2 goal, then per pilot: path, trail, vehicle) and, per pilot,
 * positions, speed and clearance sampled on the cell's time grid t (uniform, seconds).
 * window.uamViewer exposes the state for tests and for scripting from the console.
 */
(function () {
  "use strict";

  const DATA = JSON.parse(document.getElementById("uam-data").textContent);
  const plot = document.getElementById("plot");
  const flightSelect = document.getElementById("flight");
  const slider = document.getElementById("time");
  const playButton = document.getElementById("play");
  const rateSelect = document.getElementById("rate");
  const clock = document.getElementById("clock");
  const readouts = document.getElementById("readouts");
  const seeThrough = document.getElementById("seethrough");
  const FIRST_PILOT_TRACE = 3;
  const CONFIG = { responsive: true, displaylogo: false, scrollZoom: true };

  const state = { group: 0, index: 0, ready: false, busy: false, pending: null };

  function fmt(v, digits) {
    return (v === null || v === undefined || !isFinite(v)) ? "\u2013" : Number(v).toFixed(digits);
  }

  function esc(text) {
    return String(text).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;",
                                                      '"': "&quot;", "'": "&#39;" }[c]));
  }

  function group() { return DATA.groups[state.group]; }

  function optionLabel(g) {
    const who = g.pilots.map((p) => `${p.label}: ${p.outcome_words} ${fmt(p.end_t_s, 1)} s`).join("; ");
    return `${g.scenario} #${g.episode} seed ${g.seed} \u2014 ${who}`;
  }

  function status(p, t) {
    if (t <= p.end_t_s) return "flying";
    return `${p.outcome_words} at ${fmt(p.end_t_s, 1)} s`;
  }

  function buildReadouts(g) {
    readouts.innerHTML = g.pilots.map((p, i) => `
      <div class="pilot" style="border-left-color:${esc(p.color)}" data-pilot="${i}">
        <div class="name" style="color:${esc(p.color)}">${esc(p.label)}</div>
        <table>
          <tr><td>speed</td><td class="v" data-field="speed"></td><td>m/s</td></tr>
          <tr><td>clearance</td><td class="v" data-field="clearance"></td><td>m</td></tr>
          <tr><td>min clearance</td><td class="v">${fmt(p.min_clearance_m, 2)}</td><td>m</td></tr>
        </table>
        <div class="status" data-field="status"></div>
      </div>`).join("");
    const wind = g.wind && g.wind.steady_enu_m_s ? `wind (${g.wind.steady_enu_m_s.join(", ")}) m/s` : "";
    const turb = g.wind && g.wind.turbulence ? `, ${g.wind.turbulence} turbulence` : "";
    document.getElementById("about").textContent =
      `${g.description || g.scenario} \u00b7 ${g.vehicle} \u00b7 map ${g.map} \u00b7 ${wind}${turb}`;
  }

  function pilotAt(p, k, t) {
    return { x: p.x[k], y: p.y[k], z: p.z[k], speed: p.speed[k], clearance: p.clearance[k], status: status(p, t) };
  }

  /* Move trails and vehicles to grid index k: one restyle for every pilot's trail and vehicle trace. */
  function draw(k) {
    const g = group();
    const t = g.t[k];
    const xs = [], ys = [], zs = [], cds = [], traces = [];
    g.pilots.forEach((p, i) => {
      const end = Math.min(k, p.last - 1);
      const cd = [];
      for (let j = 0; j <= end; j++) cd.push([g.t[j], p.speed[j], p.clearance[j]]);
      xs.push(p.x.slice(0, end + 1), [p.x[k]]);
      ys.push(p.y.slice(0, end + 1), [p.y[k]]);
      zs.push(p.z.slice(0, end + 1), [p.z[k]]);
      cds.push(cd, [[t, p.speed[k], p.clearance[k]]]);
      traces.push(FIRST_PILOT_TRACE + 3 * i + 1, FIRST_PILOT_TRACE + 3 * i + 2);
    });
    clock.textContent = `t = ${fmt(t, 2)} s of ${fmt(g.duration_s, 2)} s`;
    g.pilots.forEach((p, i) => {
      const box = readouts.querySelector(`[data-pilot="${i}"]`);
      const now = pilotAt(p, k, t);
      box.querySelector('[data-field="speed"]').textContent = fmt(now.speed, 2);
      box.querySelector('[data-field="clearance"]').textContent = fmt(now.clearance, 2);
      box.querySelector('[data-field="status"]').textContent = now.status;
    });
    return Plotly.restyle(plot, { x: xs, y: ys, z: zs, customdata: cds }, traces);
  }

  /* Show grid index k; while a restyle is drawing, only the latest request is kept. */
  function setIndex(k) {
    const g = group();
    k = Math.max(0, Math.min(g.t.length - 1, Math.round(k)));
    state.index = k;
    slider.value = String(k);
    if (state.busy) { state.pending = k; return Promise.resolve(); }
    state.busy = true;
    return draw(k).then(() => {
      state.busy = false;
      if (state.pending !== null) { const next = state.pending; state.pending = null; return setIndex(next); }
      return undefined;
    }, (err) => { state.busy = false; throw err; });
  }

  function indexOfTime(t) {
    const g = group();
    const dt = g.t.length > 1 ? g.t[g.t.length - 1] / (g.t.length - 1) : 1;
    return Math.round(t / dt);
  }

  function select(i) {
    stop();
    state.group = i;
    state.pending = null;
    const g = group();
    flightSelect.value = String(i);
    slider.max = String(g.t.length - 1);
    buildReadouts(g);
    return Plotly.react(plot, g.figure.data, g.figure.layout, CONFIG).then(() => {
      applySeeThrough();
      return setIndex(0);
    });
  }

  /* Buildings hide paths that weave between them; see-through lets both be seen at once. */
  function applySeeThrough() {
    return Plotly.restyle(plot, { opacity: seeThrough.checked ? 0.3 : 1.0 }, [0]);
  }

  const player = window.uamPlayer({  // player.js
    button: playButton, rate: rateSelect, now: () => group().t[state.index], end: () => group().duration_s,
    show: (t) => setIndex(indexOfTime(t)),
  });
  const stop = player.stop;

  DATA.groups.forEach((g, i) => {
    const opt = document.createElement("option");
    opt.value = String(i);
    opt.textContent = optionLabel(g);
    flightSelect.appendChild(opt);
  });
  document.getElementById("run").textContent =
    `${DATA.run.folder} \u00b7 ${DATA.run.command} \u00b7 ${DATA.run.created_utc}`;
  flightSelect.addEventListener("change", () => select(Number(flightSelect.value)));
  slider.addEventListener("input", () => { stop(); setIndex(Number(slider.value)); });
  seeThrough.addEventListener("change", applySeeThrough);

  window.uamViewer = {
    data: DATA,
    select: select,
    setTime: (t) => { stop(); return setIndex(indexOfTime(t)); },
    play: player.play,
    stop: stop,
    state: () => {
      const g = group();
      const t = g.t[state.index];
      return { group: state.group, spec: g.spec, index: state.index, t: t, playing: player.playing(),
               ready: state.ready, pilots: g.pilots.map((p) => Object.assign({ label: p.label },
                                                                               pilotAt(p, state.index, t))) };
    },
  };
  window.uamViewer.loaded = select(0).then(() => { state.ready = true; document.body.dataset.ready = "1"; });
})();
