// feeder_bt tree view: the behaviour trees drawn as a graph in SVG, with each
// node's status in colour, collapsible subtrees, the blackboard, and a timeline to rewind
// (drag back: the trees and blackboard as they were then) and resume ("Live", or "Play"
// from there). The same view serves a running cell (feeder run --ui, inside the dashboard)
// and a past run (feeder replay FILE.db --ui). Data: GET /api/tree/nodes and
// /api/tree/at?t=SECONDS (feeder_bt/ui/treedata.py). Hand-made, no library, no build step.
"use strict";

(() => {
  const NS = "http://www.w3.org/2000/svg";
  const STATUS = ["invalid", "running", "success", "failure"];
  const GLYPH = {sequence: "\u2192", selector: "?", parallel: "\u21c9", decorator: "\u25c7",
                 leaf: "\u2022"};
  const NODE_W = 176, NODE_H = 20, COL = 196, ROW = 24, PAD = 6, NAME_CHARS = 24;
  const POLL_MS = 500;

  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function svg(tag, attrs, text) {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  class TreeView {
    constructor(host, live) {
      this.live = live;          // true: a running cell ("Live" follows it)
      this.nodes = [];           // [id, parent, tree, name, shape, class]
      this.kids = new Map();
      this.override = new Map(); // node id -> folded, as the user clicked it
      this.autoFold = true;      // fold the branches that are idle at the time shown
      this.state = null;
      this.prevBoard = {};
      this.following = true;     // showing the latest state
      this.playing = null;
      this.inflight = false;
      this.pending = null;
      this.timer = null;
      this.build(host);
    }

    build(host) {
      this.bar = el("div", {class: "tv-bar"});
      this.title = el("span", {class: "tv-title", id: "tv-title"}, "-");
      this.part = el("select", {id: "tv-part", title: "which tree to draw"});
      for (const p of ["ticked", "setup", "feeding", "cleanup"]) {
        this.part.append(new Option(p === "ticked" ? "the ticked tree" : p, p));
      }
      this.liveBtn = el("button", {type: "button", id: "tv-live"}, this.live ? "Live" : "End");
      this.playBtn = el("button", {type: "button", id: "tv-play"}, "\u25b6 Play 2\u00d7");
      const back = el("button", {type: "button", id: "tv-back"}, "\u2212 1 s");
      const fwd = el("button", {type: "button", id: "tv-fwd"}, "+ 1 s");
      const fold = el("button", {type: "button", id: "tv-fold"}, "Fold idle");
      const unfold = el("button", {type: "button", id: "tv-unfold"}, "Unfold all");
      this.time = el("span", {class: "tv-time", id: "tv-time"}, "t = -");
      this.bar.append(this.title, this.part, this.liveBtn, this.playBtn, back, fwd, fold,
                      unfold, this.time);
      this.slider = el("input", {type: "range", id: "tv-slider", min: "0", max: "0",
                                 step: "0.02", value: "0", "aria-label": "time"});
      this.marks = svg("svg", {class: "tv-marks", id: "tv-marks", viewBox: "0 0 1000 12",
                               preserveAspectRatio: "none"});
      const line = el("div", {class: "tv-timeline"});
      line.append(this.slider, this.marks);
      this.graph = svg("svg", {class: "tv-graph", id: "tv-graph"});
      const scroll = el("div", {class: "tv-scroll", id: "tv-scroll"});
      scroll.append(this.graph);
      this.scroll = scroll;
      this.fit = true;
      this.fitBtn = el("button", {type: "button", id: "tv-zoom"}, "Zoom 1:1");
      this.fitBtn.addEventListener("click", () => { this.fit = !this.fit; this.zoom(); });
      this.bar.insertBefore(this.fitBtn, this.time);
      window.addEventListener("resize", () => this.zoom());
      let drag = null;                    // pan: drag the background
      scroll.addEventListener("mousedown", (ev) => {
        if (ev.target.closest && ev.target.closest(".tv-node")) return;
        drag = [ev.clientX, ev.clientY, scroll.scrollLeft, scroll.scrollTop];
      });
      window.addEventListener("mouseup", () => { drag = null; });
      scroll.addEventListener("mousemove", (ev) => {
        if (!drag) return;
        scroll.scrollLeft = drag[2] - (ev.clientX - drag[0]);
        scroll.scrollTop = drag[3] - (ev.clientY - drag[1]);
      });
      this.board = el("table", {class: "tv-board", id: "tv-board"});
      const main = el("div", {class: "tv-main"});
      const side = el("div", {class: "tv-side"});
      side.append(el("h3", {}, "Blackboard"), this.board);
      main.append(scroll, side);
      const legend = el("p", {class: "legend"});
      for (const s of STATUS) {
        legend.append(el("span", {class: `tv-key st-${s}`}, s === "invalid" ? "not ticked" : s));
      }
      legend.append(document.createTextNode(
        " \u00b7 idle branches folded (dashed) \u00b7 click a node to fold or unfold it \u00b7 \u2192 sequence, ? selector, " +
        "\u21c9 parallel, \u25c7 decorator"));
      host.replaceChildren(this.bar, line, legend, main);

      this.slider.addEventListener("input", () => this.seek(Number(this.slider.value)));
      this.liveBtn.addEventListener("click", () => { this.stopPlay(); this.follow(); });
      this.playBtn.addEventListener("click", () => this.togglePlay());
      back.addEventListener("click", () => this.seek(this.shownT() - 1));
      fwd.addEventListener("click", () => this.seek(this.shownT() + 1));
      fold.addEventListener("click", () => {
        this.autoFold = true; this.override.clear(); this.draw();
      });
      unfold.addEventListener("click", () => {
        this.autoFold = false; this.override.clear(); this.draw();
      });
      this.part.addEventListener("change", () => this.draw());
    }

    // ------------------------------------------------------------ data
    start() {
      if (this.timer) return;
      if (this.live) this.follow(); else this.openReplay();
      this.timer = setInterval(() => { if (this.following) this.fetchAt(null); }, POLL_MS);
    }

    stop() {
      clearInterval(this.timer);
      this.timer = null;
      this.stopPlay();
    }

    follow() {
      this.following = true;
      this.liveBtn.classList.add("on");
      this.fetchAt(null);
    }

    shownT() { return this.state ? this.state.t : 0; }

    // A past run opens on the moment that matters: a second before its first fault (a
    // miss is not one), else a second before it stopped (its last activity), not on
    // its end, where every node is idle.
    async openReplay() {
      this.following = false;
      let st = null;
      try {
        const resp = await fetch("/api/tree/at", {credentials: "same-origin"});
        if (resp.ok) st = await resp.json();
      } catch (e) { /* no answer: the end, as before */ }
      if (!st) { this.follow(); return; }
      const [t0, t1] = st.span;
      const fault = st.marks.find(([, what]) => what.startsWith("fault"));
      const stops = st.marks.filter(([, what]) => what === "STOPPING" || what === "FAULTING");
      let t = t1, why = "end of the run";
      if (fault) {
        t = Math.max(t0, fault[0] - 1);
        why = `${(fault[0] - t).toFixed(0)} s before the first fault`;
      } else if (stops.length) {
        t = Math.max(t0, stops[stops.length - 1][0] - 1);
        why = "the last activity";
      }
      this.opened = {t: Number(t.toFixed(3)), why};
      this.seek(this.opened.t);
    }

    seek(t) {
      this.following = false;
      this.liveBtn.classList.remove("on");
      if (this.state) t = Math.min(Math.max(t, this.state.span[0]), this.state.span[1]);
      this.slider.value = String(t);
      this.fetchAt(t);
    }

    async fetchAt(t) {
      if (this.inflight) { this.pending = {t}; return; }   // only the latest wish counts
      this.inflight = true;
      try {
        const q = t === null ? "" : `?t=${encodeURIComponent(t.toFixed(3))}`;
        const resp = await fetch(`/api/tree/at${q}`, {credentials: "same-origin"});
        if (resp.ok) {
          const st = await resp.json();
          if (st.nodes > this.nodes.length) await this.fetchNodes();
          if (t !== null || this.following) this.show(st);
        } else if (resp.status === 401) {
          this.stop();
        }
      } catch (e) {
        /* the controller is gone or restarting: keep the last picture */
      } finally {
        this.inflight = false;
        if (this.pending) {
          const p = this.pending;
          this.pending = null;
          this.fetchAt(this.following ? null : p.t);
        }
      }
    }

    async fetchNodes() {
      const resp = await fetch("/api/tree/nodes", {credentials: "same-origin"});
      if (!resp.ok) return;
      this.nodes = (await resp.json()).nodes;
      this.kids = new Map();
      for (const n of this.nodes) {
        if (n[1] >= 0) {
          if (!this.kids.has(n[1])) this.kids.set(n[1], []);
          this.kids.get(n[1]).push(n[0]);
        }
      }
    }

    togglePlay() {
      if (this.playing) { this.stopPlay(); return; }
      if (this.following && this.state) this.seek(this.state.span[1] - 10);
      this.playBtn.textContent = "\u275a\u275a Pause";
      this.playing = setInterval(() => {
        const end = this.state ? this.state.span[1] : 0;
        const next = this.shownT() + 1.0;     // twice the cell's pace: catches up
        if (next >= end) {
          this.stopPlay();
          if (this.live) this.follow(); else this.seek(end);
        } else {
          this.seek(next);
        }
      }, 500);
    }

    stopPlay() {
      clearInterval(this.playing);
      this.playing = null;
      this.playBtn.textContent = "\u25b6 Play 2\u00d7";
    }

    // ------------------------------------------------------------ drawing
    show(st) {
      const old = this.state;
      this.prevBoard = old ? old.board : st.board;
      this.state = st;
      if (st.tree) this.lastTree = st.tree;
      this.slider.min = String(st.span[0]);
      this.slider.max = String(st.span[1]);
      // the slider shows the time shown: a value set before its range was known (a replay
      // opening before the first fault) was clamped to 0 by the browser
      this.slider.value = String(this.following ? st.span[1] : st.t);
      const when = this.following ? (this.live ? "live" : "end of the run")
        : this.opened && Math.abs(this.opened.t - st.t) < 1e-3 ? this.opened.why
        : `${(st.span[1] - st.t).toFixed(2)} s before the ${this.live ? "latest" : "end"}`;
      this.time.textContent = `t = ${st.t.toFixed(2)} s (${when})`;
      this.time.dataset.t = String(st.t);
      const same = old && old.t === st.t && old.tree === st.tree &&
        old.statuses.join() === st.statuses.join();
      if (same) return;                   // nothing new (a finished run): keep the drawing
      this.drawMarks();
      this.draw();
      this.drawBoard();
    }

    // Fit: the whole width of the tree in its box (a deep tree drawn smaller, never
    // larger than 1:1); 1:1: natural size, panned by dragging or with the scroll bars.
    zoom() {
      if (!this.size) return;
      const [W, H] = this.size;
      const box = Math.max(this.scroll.clientWidth - 2, 100);
      const k = this.fit ? Math.min(1, box / W) : 1;
      this.graph.setAttribute("width", (W * k).toFixed(1));
      this.graph.setAttribute("height", (H * k).toFixed(1));
      this.graph.dataset.scale = k.toFixed(3);
      this.fitBtn.textContent = this.fit ? "Zoom 1:1" : "Zoom to fit";
    }

    treeName() {
      const want = this.part.value;
      if (want !== "ticked") return want;
      return (this.state && this.state.tree) || this.lastTree || "feeding";
    }

    idle(id) {
      return this.state.statuses[id] === 0 &&
        (this.kids.get(id) || []).every((k) => this.idle(k));
    }

    folded(id) {
      if (this.override.has(id)) return this.override.get(id);
      return this.autoFold && this.nodes[id][1] >= 0 && this.kids.has(id) && this.idle(id);
    }

    draw() {
      const st = this.state;
      if (!st) return;
      const tree = this.treeName();
      this.title.textContent = st.tree ? `Trees: ${st.tree} ticked` : "Trees: none ticked";
      const items = [];
      let row = 0;
      const place = (id, depth) => {    // tidy layout: leaves in rows, parents centred
        const kids = this.folded(id) ? [] : (this.kids.get(id) || []);
        const item = {id, depth, y: 0, kids: []};
        items.push(item);
        if (!kids.length) { item.y = row++; return item; }
        item.kids = kids.map((k) => place(k, depth + 1));
        item.y = (item.kids[0].y + item.kids[item.kids.length - 1].y) / 2;
        return item;
      };
      for (const n of this.nodes) if (n[2] === tree && n[1] < 0) place(n[0], 0);
      const depth = Math.max(0, ...items.map((i) => i.depth));
      const W = (depth + 1) * COL + PAD * 2, H = Math.max(row, 1) * ROW + PAD * 2;
      this.graph.setAttribute("viewBox", `0 0 ${W} ${H}`);
      this.size = [W, H];
      this.zoom();
      const edges = [], boxes = [];
      const xy = (it) => [PAD + it.depth * COL, PAD + it.y * ROW];
      for (const it of items) {
        const [x, y] = xy(it);
        for (const k of it.kids) {
          const [x2, y2] = xy(k);
          const x1 = x + NODE_W, ym = y + NODE_H / 2, y2m = y2 + NODE_H / 2, xm = (x1 + x2) / 2;
          edges.push(svg("path", {d: `M${x1},${ym} C${xm},${ym} ${xm},${y2m} ${x2},${y2m}`,
                                  class: `tv-edge st-${STATUS[st.statuses[k.id] || 0]}`}));
        }
        boxes.push(this.box(it, x, y, st));
      }
      this.graph.replaceChildren(...edges, ...boxes);
    }

    box(it, x, y, st) {
      const n = this.nodes[it.id];
      const status = STATUS[st.statuses[it.id] || 0];
      const hidden = this.folded(it.id) ? this.count(it.id) : 0;
      const g = svg("g", {class: `tv-node st-${status}${hidden ? " folded" : ""}`,
                          "data-id": it.id, "data-name": n[3], "data-status": status,
                          transform: `translate(${x},${y})`});
      let name = n[3].length > NAME_CHARS ? n[3].slice(0, NAME_CHARS - 1) + "\u2026" : n[3];
      if (hidden) name += ` +${hidden}`;
      g.append(svg("title", {}, `${n[3]} (${n[4]} ${n[5]}): ${status}`),
               svg("rect", {width: NODE_W, height: NODE_H, rx: 4}),
               svg("text", {x: 6, y: 14, class: "glyph"}, GLYPH[n[4]] || ""),
               svg("text", {x: 20, y: 14}, name));
      if (this.kids.has(it.id)) {
        g.classList.add("composite");
        g.addEventListener("click", () => {
          this.override.set(it.id, !hidden);
          this.draw();
        });
      }
      return g;
    }

    count(id) {
      return (this.kids.get(id) || []).reduce((s, k) => s + 1 + this.count(k), 0);
    }

    drawMarks() {
      const st = this.state;
      const [t0, t1] = st.span;
      const span = Math.max(t1 - t0, 1e-9);
      const marks = [];
      for (const [t, what] of st.marks) {
        const x = ((t - t0) / span * 1000).toFixed(1);
        const m = svg("line", {x1: x, x2: x, y1: 0, y2: 12,
                               class: what.startsWith("fault") ? "fault"
                                 : what.startsWith("miss") ? "miss" : "state"});
        m.append(svg("title", {}, `${t.toFixed(2)} s: ${what}`));
        m.addEventListener("click", () => this.seek(t));
        marks.push(m);
      }
      this.marks.replaceChildren(...marks);
    }

    drawBoard() {
      const rows = [];
      for (const [k, v] of Object.entries(this.state.board)) {
        const tr = el("tr", {});
        if (JSON.stringify(this.prevBoard[k]) !== JSON.stringify(v)) tr.className = "changed";
        const text = v === null ? "-" : String(v);
        tr.append(el("th", {}, k), el("td", {title: text}, text));
        rows.push(tr);
      }
      this.board.replaceChildren(...rows);
    }
  }

  window.feederTree = {
    mount(host, live) { return new TreeView(host, live); },
  };
})();
