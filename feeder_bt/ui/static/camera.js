// Camera view: the last frame the cell located parts in, as the controller drew
// it (parts green with class, pose, x, y and angle; rejected blobs red with the reason),
// and the same list as text. Asks /api/camera at most as often as the controller allows
// (its `fps`, a setting), and only while the dashboard is shown; a 429 says when to ask
// again. The picture itself is made by the controller's web thread, never by the cell.
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);
  let seq = null;
  let period = 500;

  function fmt(v) { return Number(v).toFixed(1).replace(/\.0$/, ""); }

  function show(d) {
    const img = $("camera-img");
    img.src = d.image;
    img.dataset.seq = String(d.seq);
    img.alt = `camera frame ${d.frame}: ${d.parts.length} part(s) located, ` +
      `${d.rejected.length} blob(s) rejected`;
    $("camera-info").textContent = `frame ${d.frame}: ${d.parts.length} part(s) located, ` +
      `${d.rejected.length} blob(s) rejected (vision ${fmt(d.vision_ms)} ms)`;
    const list = $("camera-list");
    list.replaceChildren();
    for (const p of d.parts) {
      const li = document.createElement("li");
      li.className = "cam-part";
      li.textContent = `${p.part}/${p.pose}${p.pickable ? "" : " (no pick)"}  ` +
        `x ${fmt(p.x_mm)} mm, y ${fmt(p.y_mm)} mm, ${fmt(p.angle_deg)}\u00b0`;
      list.appendChild(li);
    }
    for (const r of d.rejected) {
      const li = document.createElement("li");
      li.className = "cam-reject";
      li.textContent = `rejected at x ${fmt(r.x_mm)}, y ${fmt(r.y_mm)}: ${r.reason}`;
      list.appendChild(li);
    }
  }

  async function poll() {
    let wait = period;
    if (!$("dashboard").hidden) {
      try {
        const resp = await fetch("/api/camera", {credentials: "same-origin"});
        const d = await resp.json();
        if (resp.status === 429) {
          wait = 1000 * Number(resp.headers.get("retry-after") || 1);
        } else if (resp.ok && d.ok) {
          period = 1000 / (d.fps || 2);
          wait = period;
          if (d.seq === null) $("camera-info").textContent = d.why;
          else if (d.seq !== seq) { seq = d.seq; show(d); }
        } else {
          wait = 2000;                      // logged out, or no camera in this run
          if (resp.status === 404) $("camera-info").textContent = d.error;
        }
      } catch (e) {
        wait = 2000;                        // the controller is restarting or gone
      }
    }
    setTimeout(poll, wait);
  }

  poll();
})();
