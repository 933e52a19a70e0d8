// feeder_bt operator page: log in, watch the cell live over a websocket, and — when this
// session holds control — operate it. No framework and no build step; everything the page
// needs is served by the controller itself. The server decides what is allowed: every
// button sends its request, and a refusal comes back with the reason.
"use strict";

const $ = (id) => document.getElementById(id);
const SVG = "http://www.w3.org/2000/svg";
const MAX_MESSAGES = 200;
const MAX_POINTS = 600;

let socket = null;
let loggedIn = false;
let history = [];          // [up time s, parts/min, queue]
let lastStatus = null;
let treeView = null;       // tree.js: the graph, the blackboard and the timeline

async function api(path, body) {
  const opts = {credentials: "same-origin", headers: {}};
  if (body !== undefined) {
    opts.method = "POST";
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  let resp;
  try {
    resp = await fetch(path, opts);
  } catch (e) {
    return {status: 0, data: {ok: false, error: "the controller does not answer"}};
  }
  let data = {};
  try { data = await resp.json(); } catch (e) { data = {ok: false, error: resp.statusText}; }
  return {status: resp.status, data};
}

let noticeTimer = null;

function notice(text, ok) {
  const n = $("notice");
  n.textContent = text || "";
  n.className = "notice " + (ok ? "ok" : "error");
  clearTimeout(noticeTimer);          // an answer is news for a while, not for ever
  noticeTimer = setTimeout(() => { n.textContent = ""; n.className = "notice"; }, 10000);
}

function fmtDuration(s) {
  if (s === null || s === undefined) return "-";
  s = Math.max(0, Math.floor(s));
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return `${h}:${String(m).padStart(2, "0")}:${String(sec).padStart(2, "0")}`;
}

function fmt(v, digits = 0) {
  return (v === null || v === undefined) ? "-" : Number(v).toFixed(digits);
}

// ---------------------------------------------------------------- login / logout

function showLogin(message) {
  loggedIn = false;
  if (socket) { socket.onclose = null; socket.close(); socket = null; }
  $("dashboard").hidden = true;
  $("logout").hidden = true;
  $("login").hidden = false;
  $("who").textContent = "";
  $("control-state").textContent = "Control: -";
  $("control-state").dataset.state = "";
  if (treeView) treeView.stop();
  $("login-error").textContent = message || "";
  $("login-password").value = "";
  $("login-user").focus();
}

function showDashboard(session) {
  loggedIn = true;
  $("login").hidden = true;
  $("dashboard").hidden = false;
  $("logout").hidden = false;
  renderSession(session);
  connect();
  if (!treeView && window.feederTree) treeView = window.feederTree.mount($("tree-view"), true);
  if (treeView) treeView.start();
}

$("login-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  $("login-error").textContent = "";
  const {status, data} = await api("/api/login", {
    user: $("login-user").value, password: $("login-password").value});
  if (status === 200 && data.ok) {
    $("login-password").value = "";
    showDashboard(data);
  } else {
    $("login-error").textContent = data.error || `login failed (${status})`;
  }
});

$("logout").addEventListener("click", async () => {
  await api("/api/logout", {});
  showLogin("logged out");
});

// ---------------------------------------------------------------- live updates

function connect() {
  if (socket) return;
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${proto}//${location.host}/ws`);
  socket.onmessage = (ev) => update(JSON.parse(ev.data));
  socket.onclose = () => {
    socket = null;
    if (loggedIn) setTimeout(recheck, 1000);
  };
}

async function recheck() {
  if (!loggedIn) return;
  const {status, data} = await api("/api/me");
  if (status === 200 && data.ok) { renderSession(data); connect(); }
  else if (status === 401) showLogin("your session has ended: log in again");
  else setTimeout(recheck, 2000);            // the controller is restarting or gone
}

function update(msg) {
  if (msg.type === "logout") { showLogin("your session has ended: log in again"); return; }
  if (msg.session) renderSession(msg.session);
  if (msg.status) renderStatus(msg.status);
  if (msg.status && window.feederBelt) window.feederBelt.update(msg.status.belt);
  if (msg.history && msg.history.length) {
    history = history.concat(msg.history).slice(-MAX_POINTS);
    drawCharts();
  }
  if (msg.messages && msg.messages.length) addMessages(msg.messages);
}

function renderSession(s) {
  $("who").textContent = s.user ? `logged in as ${s.user}` : "";
  const c = s.control || {};
  const el = $("control-state");
  el.dataset.state = c.state || "";
  const leaving = (c.free_in !== undefined && c.free_in !== null)
    ? ` \u2014 control free in ${c.free_in} s` : "";   // the holder has no page open
  el.textContent = c.state === "you" ? "Control: you have control"
    : c.state === "other" && c.same_user
      ? `Control: your other session has control (${c.holder}, another tab or browser)` +
        leaving
    : c.state === "other" ? `Control: someone else has control (${c.holder})${leaving}`
    : "Control: available";
  $("force").hidden = !(s.admin && c.state === "other");
  $("st-users").textContent = (s.users || []).join(", ") || "-";
  document.body.dataset.control = c.state || "";
  controlState = c.state || "";
  applyButtons();
}

// With control, a button that does not apply in the cell's state is disabled (Start while
// it runs, Take control while you hold it). Without control they stay enabled: a click is
// refused with who holds control, which is the answer the operator needs.
let controlState = "";
const APPLIES = {
  start: (s) => s === "STOPPED",
  pause: (s) => s === "RUNNING",
  resume: (s) => s === "PAUSED",
  stop: (s) => s === "STARTING" || s === "RUNNING" || s === "PAUSED",
  reset: (s) => s === "FAULT",
  load: (s) => s === "STOPPED" || s === "FAULT",
};

function applyButtons() {
  const you = controlState === "you";
  const state = lastStatus ? lastStatus.state : "";
  for (const [id, ok] of Object.entries(APPLIES)) $(id).disabled = you && state !== "" && !ok(state);
  $("take").disabled = you;
}

function renderStatus(st) {
  lastStatus = st;
  const badge = $("state-badge");
  badge.textContent = st.state;
  badge.dataset.state = st.state;
  $("scenario-name").textContent = st.scenario ? `${st.scenario} on ${st.cell}` : "";
  $("st-state").textContent = st.state;
  $("st-scenario").textContent = st.scenario || "-";
  const lp = st.last_part;
  $("st-last").textContent = lp ? `${lp.type} #${lp.id} at ${fmtDuration(lp.t)}` : "-";
  $("st-total").textContent = String(st.total_fed);
  $("st-ppm").textContent = fmt(st.ppm, 1);
  $("st-run").textContent = fmtDuration(st.run_time_s);
  $("st-up").textContent = fmtDuration(st.up_time_s);
  $("st-queue").textContent = String(st.queue);
  $("st-counts").textContent = `${st.located} / ${st.missed} / ${st.too_far}`;
  $("st-misoriented").textContent = st.misoriented == null ? "-" : String(st.misoriented);
  $("st-scrapped").textContent = st.scrapped == null ? "-" : String(st.scrapped);
  const sp = st.speeds || {};
  $("st-speeds").textContent = `horizontal ${fmt(sp.horizontal_mm_s)} mm/s, inclined ` +
    `${fmt(sp.incline_pct)} %, robot ${fmt(sp.robot_speed_pct)} %`;
  $("st-hal-horizontal").textContent = `${fmt(st.hal.horizontal_mm_s)} mm/s`;
  $("st-hal-incline").textContent = `${fmt(st.hal.incline_mm_s)} mm/s`;
  $("st-faults").textContent = `${st.faults} (${st.recovered}) / ${st.misses}`;
  $("st-fault").textContent = st.fault || "-";
  $("adjust-state").textContent = st.adjuster
    ? `${st.adjuster}, ${st.auto_adjust ? "engaged" : "disengaged"}` : "-";
  $("horizontal").max = st.limits.horizontal_max_mm_s;
  for (const [id, key] of [["horizontal", "horizontal_mm_s"], ["incline", "incline_pct"],
                           ["robot", "robot_speed_pct"]]) {
    $(id).placeholder = fmt(sp[key]);
  }
  const sel = $("scenario-select");
  const names = (st.scenarios || []).join("\n");
  if (sel.dataset.names !== names) {
    sel.dataset.names = names;
    sel.replaceChildren(...st.scenarios.map((n) => new Option(n, n)));
  }
  if (document.activeElement !== sel && st.scenario_file) sel.value = st.scenario_file;
  $("tree-part").textContent = st.tree_part ? `(${st.tree_part})` : "(no tree is ticked)";
  renderTree(st.tree);
  applyButtons();
}

// py_trees' unicode drawing, with each node's [status] coloured
const STATUS_CLASS = {"✓": "st-success", "✕": "st-failure", "*": "st-running", "-": "st-idle"};

function renderTree(text) {
  const pre = $("tree");
  const nodes = [];
  for (const line of (text || "").split("\n")) {
    const m = line.match(/^(.*?)\[(✓|✕|\*|-)\](.*)$/);
    if (m) {
      nodes.push(document.createTextNode(m[1]));
      const span = document.createElement("span");
      span.className = STATUS_CLASS[m[2]];
      span.textContent = `[${m[2]}]`;
      nodes.push(span, document.createTextNode(m[3] + "\n"));
    } else {
      nodes.push(document.createTextNode(line + "\n"));
    }
  }
  pre.replaceChildren(...nodes);
}

function addMessages(list) {
  const ol = $("messages");
  for (const m of list) {
    const li = document.createElement("li");
    li.className = `msg-${m.kind}`;
    const t = document.createElement("time");
    t.textContent = fmtDuration(m.t);
    li.append(t, document.createTextNode(" " + m.text));
    ol.prepend(li);
  }
  while (ol.children.length > MAX_MESSAGES) ol.lastChild.remove();
}

// ---------------------------------------------------------------- charts (hand-made SVG)

function drawChart(svg, points, unit) {
  const W = 400, H = 120, PAD = 4;
  const nodes = [];
  if (points.length) {
    const t0 = points[0][0], t1 = Math.max(points[points.length - 1][0], t0 + 1);
    const top = Math.max(1, ...points.map((p) => p[1])) * 1.15;
    const xy = points.map(([t, v]) =>
      `${((t - t0) / (t1 - t0) * (W - 2 * PAD) + PAD).toFixed(1)},` +
      `${(H - PAD - v / top * (H - 2 * PAD)).toFixed(1)}`);
    const grid = document.createElementNS(SVG, "line");
    for (const [k, v] of Object.entries({x1: 0, x2: W, y1: H - PAD, y2: H - PAD})) {
      grid.setAttribute(k, v);
    }
    grid.setAttribute("class", "axis");
    const line = document.createElementNS(SVG, "polyline");
    line.setAttribute("points", xy.join(" "));
    line.setAttribute("class", "series");
    const label = document.createElementNS(SVG, "text");
    label.setAttribute("x", PAD + 2);
    label.setAttribute("y", 14);
    label.setAttribute("class", "label");
    const last = points[points.length - 1][1];
    label.textContent = `now ${last.toFixed(unit === "parts/min" ? 1 : 0)} ${unit} · ` +
      `max ${(top / 1.15).toFixed(0)} · last ${fmtDuration(t1 - t0)}`;
    nodes.push(grid, line, label);
  }
  svg.replaceChildren(...nodes);
}

function drawCharts() {
  drawChart($("chart-ppm"), history.map((h) => [h[0], h[1]]), "parts/min");
  drawChart($("chart-queue"), history.map((h) => [h[0], h[2]]), "parts");
}

// ---------------------------------------------------------------- operating

async function command(name, args) {
  const {status, data} = await api("/api/command", {command: name, ...(args || {})});
  notice(data.ok ? data.message : (data.error || `failed (${status})`), data.ok);
  if (status === 401) showLogin("your session has ended: log in again");
}

async function controlAction(action) {
  const {status, data} = await api("/api/control", {action});
  notice(data.ok ? data.message : (data.error || `failed (${status})`), data.ok);
  if (data.control) renderSession(data);
}

$("take").addEventListener("click", () => controlAction("take"));
$("release").addEventListener("click", () => controlAction("release"));
$("force").addEventListener("click", () => controlAction("force-release"));
for (const b of document.querySelectorAll("button[data-command]")) {
  b.addEventListener("click", () => command(b.dataset.command));
}
for (const b of document.querySelectorAll("button[data-speed]")) {
  b.addEventListener("click", () => {
    const input = $(b.dataset.input);
    if (input.value.trim() === "") { notice("type a value first", false); return; }
    command("speeds", {[b.dataset.speed]: Number(input.value)});
  });
}
$("load").addEventListener("click", () =>
  command("load", {scenario: $("scenario-select").value}));
$("adjust-on").addEventListener("click", () => command("adjust", {engaged: true}));
$("adjust-off").addEventListener("click", () => command("adjust", {engaged: false}));

// ---------------------------------------------------------------- start

(async () => {
  const {status, data} = await api("/api/me");
  if (status === 200 && data.ok) showDashboard(data);
  else showLogin("");
})();
