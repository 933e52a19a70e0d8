// Belt view: the horizontal belt in plan, drawn from the controller's own data
// (status.belt: the queued parts moved by the robot's belt encoder since their latch, the
// camera window through the calibration, the robot's reach and too_far). The belt runs
// left to right; y across it grows downwards as in the camera picture.
"use strict";

window.feederBelt = (() => {
  const SVG = "http://www.w3.org/2000/svg";
  const MARGIN = 20;

  function el(name, attrs, text) {
    const e = document.createElementNS(SVG, name);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function partShape(p, cls) {
    const g = el("g", {class: cls, "data-id": String(p.id),
                       transform: `translate(${p.x_mm} ${p.y_mm})`});
    const r = p.r_mm || 12;
    g.appendChild(el("circle", {r: String(r)}));
    const a = p.angle_deg * Math.PI / 180;
    g.appendChild(el("line", {x1: "0", y1: "0", x2: String(r * Math.cos(a)),
                              y2: String(r * Math.sin(a))}));
    g.appendChild(el("text", {x: String(r + 3), y: "4"}, `#${p.id}`));
    return g;
  }

  function update(b) {
    const svg = document.getElementById("belt");
    if (!svg || !b) return;
    const rob = b.robot;
    const right = Math.max(b.length_mm, rob.base_mm[0] + 40);
    svg.setAttribute("viewBox", `${-MARGIN} ${-MARGIN - 20} ${right + 2 * MARGIN} ` +
                                `${b.width_mm + 2 * MARGIN + 20}`);
    svg.replaceChildren();
    // a plate cell: the plate's rectangle in the same frame, its parts still
    const area = b.plate ? {x: b.plate.origin_mm[0], y: b.plate.origin_mm[1],
                            w: b.plate.size_mm[0], h: b.plate.size_mm[1]}
                         : {x: 0, y: 0, w: b.length_mm, h: b.width_mm};
    const box = {x: String(area.x), y: String(area.y), width: String(area.w),
                 height: String(area.h)};
    const clip = el("clipPath", {id: "belt-clip"});
    clip.appendChild(el("rect", box));
    svg.appendChild(clip);
    svg.appendChild(el("rect", {class: "belt", ...box}));
    // the robot's window: its reach about the base, less the inner reach, on the belt
    const reach = el("g", {"clip-path": "url(#belt-clip)", class: "reach"});
    const [bx, by] = rob.base_mm;
    const R = rob.reach_mm, r = rob.inner_reach_mm;
    reach.appendChild(el("path", {"fill-rule": "evenodd", d:
      `M ${bx - R} ${by} a ${R} ${R} 0 1 0 ${2 * R} 0 a ${R} ${R} 0 1 0 ${-2 * R} 0 Z ` +
      `M ${bx - r} ${by} a ${r} ${r} 0 1 0 ${2 * r} 0 a ${r} ${r} 0 1 0 ${-2 * r} 0 Z`}));
    svg.appendChild(reach);
    svg.appendChild(el("circle", {class: "robot-base", cx: String(bx), cy: String(by), r: "10"}));
    svg.appendChild(el("text", {class: "label", x: String(bx - 30), y: String(by + 28)}, "robot"));
    if (b.too_far_mm !== null) {
      svg.appendChild(el("line", {class: "too-far", x1: String(b.too_far_mm), y1: "0",
                                  x2: String(b.too_far_mm), y2: String(b.width_mm)}));
      svg.appendChild(el("text", {class: "label", x: String(b.too_far_mm - 60), y: "-6"},
                         "too far"));
    }
    svg.appendChild(el("polygon", {class: "camera-window",
                                   points: b.camera.map((c) => c.join(",")).join(" ")}));
    svg.appendChild(el("text", {class: "label", x: String(b.camera[0][0] + 4), y: "-6"},
                       "camera"));
    svg.appendChild(el("text", {class: "label", x: String(area.x), y: String(area.y + area.h + 16)},
                       b.plate ? "plate: feed forward \u2192" : "belt travel \u2192"));
    const parts = el("g", {id: "belt-parts"});
    for (const p of b.parts) parts.appendChild(partShape(p, "part"));
    // a gripped part is off the belt (where the gripper is, the robot's frame would say)
    if (b.picking && b.picking.phase === "pick") parts.appendChild(partShape(b.picking,
                                                                           "part picking"));
    svg.appendChild(parts);
    const info = document.getElementById("belt-info");
    const pick = b.picking ? `; part #${b.picking.id} ${b.picking.phase === "pick" ?
      "being picked" : "in the gripper"}` : "";
    info.textContent = `${b.parts.length} part(s) queued${pick}`;
  }

  return {update};
})();
