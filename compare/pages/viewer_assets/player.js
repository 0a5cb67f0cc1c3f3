/* uam-compare pages' playback (the viewer's and the training page's Play/Pause): simulated time advances with the
 * wall clock times the chosen rate, and the page draws the time reached, frame by frame.
 *
 * window.uamPlayer({ button, rate, now, end, show }) with
 *   button: the Play/Pause button; rate: the select whose value is the playback speed (x real time);
 *   now(): the simulated time the page shows [s]; end(): the last time of the flight [s];
 *   show(t): draw time t [s], clamped by the page to its time grid (a promise: the next frame waits for it).
 * returns { play, stop, playing() }.
 */
window.uamPlayer = function (opts) {
  "use strict";

  const st = { playing: false, simTime: 0, lastWall: null };

  function frame(wall) {
    if (!st.playing) return;
    if (st.lastWall !== null) st.simTime += (wall - st.lastWall) / 1000 * Number(opts.rate.value);
    st.lastWall = wall;
    if (st.simTime >= opts.end()) { opts.show(opts.end()); stop(); return; }
    Promise.resolve(opts.show(st.simTime)).then(() => requestAnimationFrame(frame));
  }

  function play() {
    st.simTime = opts.now() >= opts.end() ? 0 : opts.now();  // from the start again once at the end
    st.playing = true;
    st.lastWall = null;
    opts.button.innerHTML = "&#10074;&#10074; Pause";
    opts.button.setAttribute("aria-label", "pause");
    requestAnimationFrame(frame);
  }

  function stop() {
    st.playing = false;
    opts.button.innerHTML = "&#9654; Play";
    opts.button.setAttribute("aria-label", "play");
  }

  opts.button.addEventListener("click", () => (st.playing ? stop() : play()));
  return { play: play, stop: stop, playing: () => st.playing };
};
