// The operator GUI: wires the connection, the fleet model, the map, the chart and the controls.

import { Connection, loggedIn } from "./connection.js";
import { FleetModel, fmtS } from "./model.js";
import { MapView, robotColor } from "./mapview.js";
import { SlackChart } from "./chart.js";
import { TaskBoard } from "./tasks.js";

const $ = (id) => document.getElementById(id);
const model = new FleetModel();
const mapView = new MapView($("map"), $("map-wrap"));
const chart = new SlackChart($("chart"));
let armed = false; // the next map click places an intruder
let snapshotAsked = 0; // performance.now() of the outstanding get_snapshot (0: none)
let tableDrawn = 0;
let logDirty = false; // events arrived since the log was drawn (drawn at most 4 times a second)
let logDrawn = 0;

const scheme = location.protocol === "https:" ? "wss" : "ws";
const url = `${scheme}://${location.host}/ws`; // the login cookie authenticates it
if (!(await loggedIn())) {
  location.replace(`/login${location.hash}`);
  await new Promise(() => {}); // the page is being replaced
}
const conn = new Connection(url, { onMessage, onLink });
// shown, and reading the task API, only once a snapshot says the gateway runs a shift
const taskBoard = new TaskBoard($("tasks-card"), (t, text) => {
  model.note(t, text, "plan");
  logDirty = true;
});

// ------------------------------------------------------------------------- incoming
function onMessage(msg) {
  if (msg.type === "snapshot") {
    snapshotAsked = 0;
    if (msg.lifelong && !taskBoard.started) {
      model.note(msg.t_ms, `lifelong shift on ${msg.map_name}: ${msg.robots.length} robots`);
      logDirty = true;
      taskBoard.start();
    }
    model.applySnapshot(msg);
    mapView.setRows(msg.rows);
    showInstance(msg);
    syncControls();
    renderPanels();
  } else if (msg.type === "event") {
    model.applyEvent(msg);
    if (["status", "plan", "summary"].includes(msg.event)) askSnapshot(true);
    if (msg.event === "status" || msg.event === "plan") syncControls();
    if (msg.event !== "slack") logDirty = true;
  } else if (msg.type === "error") {
    notify(`gateway: ${msg.code} ${msg.detail}`, true);
  }
}

function onLink(state, detail) {
  const el = $("link");
  el.dataset.state = state;
  el.textContent = state === "on" ? "live"
    : state === "refused" ? `refused by the gateway: ${detail} (open /?token=<operator token>)`
      : `offline: ${detail}`;
  if (state === "on") askSnapshot(true);
  syncControls();
}

let shownInstance = ""; // the loaded instance the Instance form last showed

/** Show the gateway's loaded instance (or shift) in the Instance form when it changes (a
 * page opened on a running demo shows what runs), never while the operator is editing it. */
function showInstance(snap) {
  const robots = (snap.robots || []).length;
  const key = `${snap.map_name}|${snap.scen_name}|${robots}`;
  if (!snap.map_name || key === shownInstance) return;
  if ($("load-form").contains(document.activeElement)) return;
  shownInstance = key;
  $("map-name").value = snap.map_name;
  $("scen-name").value = snap.scen_name || ""; // none: a generated instance
  if (robots > 0) $("agents").value = String(robots);
}

function askSnapshot(force = false) {
  const now = performance.now();
  if (!force && snapshotAsked && now - snapshotAsked < 2000) return;
  if (conn.send("get_snapshot") !== null) snapshotAsked = now;
}

// ------------------------------------------------------------------------- commands
/** Send a command; its refusal is shown in `noteId`, next to the control that sent it. */
async function command(type, fields, label, noteId = "run-note") {
  const note = $(noteId);
  note.textContent = "";
  const reply = await conn.command(type, fields);
  if (reply.type === "ok") {
    notify(reply.detail || `${label}: ok`);
  } else {
    note.textContent = `${label} refused: ${reply.detail || reply.code}`;
  }
  askSnapshot(true);
  return reply;
}

function notify(text, error = false) {
  const el = $("notice");
  el.textContent = text;
  el.classList.toggle("error", error);
}

$("btn-start").addEventListener("click", () => command("start", {}, "start"));
$("btn-pause").addEventListener("click", () => command("pause", {}, "pause"));
$("btn-resume").addEventListener("click", () => command("resume", {}, "resume"));
$("btn-replan").addEventListener("click", () => command("replan_now", {}, "replan"));

$("speed").addEventListener("input", () => {
  $("speed-out").textContent = `${Number($("speed").value)}×`;
});
$("speed").addEventListener("change", () =>
  command("set_speed", { speed: Number($("speed").value) }, "speed"));
$("policy").addEventListener("change", () =>
  command("set_policy", { policy: $("policy").value }, "policy"));
$("threshold").addEventListener("change", () => {
  const v = Number($("threshold").value);
  if (Number.isFinite(v) && v >= 0) command("set_threshold", { threshold_ms: v }, "threshold");
  else notify("threshold must be a number of milliseconds ≥ 0", true);
});

function setArmed(on) {
  armed = on;
  $("btn-intruder").setAttribute("aria-pressed", String(on));
  $("intruder-hint").hidden = !on;
  $("map").classList.toggle("arming", on);
  if (!on) mapView.hover = null;
}
$("btn-intruder").addEventListener("click", () => setArmed(!armed));

$("map").addEventListener("pointermove", (ev) => {
  mapView.hover = armed ? mapView.cellAt(ev) : null;
});
$("map").addEventListener("pointerleave", () => {
  mapView.hover = null;
});
$("map").addEventListener("click", (ev) => {
  if (!armed) return;
  const cell = mapView.cellAt(ev);
  if (!cell || !mapView.isFree(...cell)) {
    notify("pick a free cell of the map for the intruder", true);
    return;
  }
  const seconds = Number($("intruder-s").value);
  if (!(seconds > 0)) {
    notify("the intruder's time must be a positive number of seconds", true);
    return;
  }
  setArmed(false);
  command("place_intruder", { cell, duration_ms: seconds * 1000 }, "intruder");
});

$("generate").addEventListener("change", syncControls);
$("load-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const fields = { map: $("map-name").value.trim(), agents: Number($("agents").value) };
  if ($("generate").checked) fields.generate = { seed: Number($("gen-seed").value) || 0 };
  else if ($("scen-name").value.trim()) fields.scen = $("scen-name").value.trim();
  notify(`planning ${fields.map} with ${fields.agents} robots…`);
  command("load_instance", fields, "load", "load-note");
});

// ------------------------------------------------------------------------- rendering
const BUSY = new Set(["running", "paused", "replanning", "planning"]);

function syncControls() {
  const s = model.snap;
  const status = model.status;
  const live = conn.connected;
  const badge = $("status");
  badge.textContent = live ? status : "offline";
  badge.dataset.status = live ? status : "offline";
  $("btn-start").disabled = !live || !(status === "loaded" || status === "done");
  $("btn-pause").disabled = !live || !(status === "running" || status === "replanning");
  $("btn-resume").disabled = !live || status !== "paused";
  const budgetUsed = !!s && !s.lifelong && s.replans >= s.max_replans; // a shift has none
  $("btn-replan").disabled = !live || status !== "running" || budgetUsed;
  $("btn-replan").title = budgetUsed
    ? `the run's replan budget is used (${s.replans} of ${s.max_replans})` : "";
  const shift = !!s && !!s.lifelong; // a shift's map and robots come from the configuration
  $("btn-load").disabled = !live || BUSY.has(status) || shift;
  for (const id of ["map-name", "scen-name", "generate", "gen-seed", "agents"]) {
    $(id).disabled = shift || (id === "scen-name" && $("generate").checked);
  }
  $("instance-hint").hidden = !shift;
  const worlds = s ? s.worlds : 0;
  $("btn-intruder").disabled = !live || !worlds || !s.map_name;
  $("btn-intruder").title = worlds ? "" : "no simulated world is connected to place one";
  if (armed && $("btn-intruder").disabled) setArmed(false);
  if (!s) return;
  const focused = document.activeElement;
  if (focused !== $("policy")) $("policy").value = s.policy;
  if (focused !== $("threshold")) $("threshold").value = String(s.threshold_ms);
  if (focused !== $("speed")) {
    $("speed").value = String(s.speed);
    $("speed-out").textContent = `${s.speed}×`;
  }
  const thresholded = shift || ["slack", "informed", "reschedule+slack"].includes(s.policy);
  $("threshold").disabled = !thresholded;
  $("policy").disabled = shift; // a shift plans a window every period, whatever the policy
  $("policy").title = shift ? "a lifelong shift plans a window every period" : "";
  $("policy-now").textContent = shift
    ? `window every ${fmtS(s.period_ms)}, early at slack > ${fmtS(s.threshold_ms)}`
    : thresholded ? `${s.policy}: slack > ${fmtS(s.threshold_ms)}` : s.policy;
}

function renderPanels() {
  const s = model.snap;
  if (!s) return;
  const plan = $("plan-now");
  plan.textContent = s.lifelong ? "lifelong shift" : s.plan === null ? "–"
    : `#${s.plan} (${s.replans} replan${s.replans === 1 ? "" : "s"})`;
  $("legend-goal").hidden = !!s.lifelong;
  $("legend-errands").hidden = !s.lifelong;
  plan.dataset.plan = s.plan === null ? "" : String(s.plan);
  $("map-now").textContent = s.map_name ? `${s.map_name} · ${s.robots.length} robots` : "–";
  $("exec-costs").hidden = !!s.lifelong; // a shift has no SOC, makespan or plan costs
  taskBoard.shiftRate(s.tasks_per_min);
  const hasRun = s.plan !== null && !s.lifelong;
  $("soc").textContent = hasRun ? fmtS(s.soc_ms) : "–";
  $("makespan").textContent = hasRun ? fmtS(s.makespan_ms) : "–";
  $("est-soc").textContent = hasRun ? fmtS(s.est_soc_ms) : "–";
  $("est-makespan").textContent = hasRun ? fmtS(s.est_makespan_ms) : "–";
  const base = model.planCosts();
  $("plan-soc").textContent = base ? fmtS(base.soc) : "–";
  $("plan-makespan").textContent = base ? fmtS(base.makespan) : "–";
  const a = s.actions;
  const total = a.pending + a.dispatched + a.running + a.blocked + a.finished;
  $("progress").max = Math.max(1, total);
  $("progress").value = a.finished;
  $("progress-text").textContent = s.plan === null ? "no run yet"
    : s.lifelong ? `${a.finished} actions done, ${total - a.finished} committed`
      : `${a.finished} / ${total} actions of plan #${s.plan}`;
  const count = (activity) => s.robots.filter((r) => r.activity === activity).length;
  $("map").setAttribute("aria-label", s.map_name
    ? `Map ${s.map_name}: ${s.robots.length} robots, ${count("running")} moving, `
      + `${count("blocked")} blocked, ${s.waits.length} waiting for another robot, `
      + `${s.intruders.length} intruder(s)`
    : "Map: no instance loaded");
  const now = performance.now();
  if (now - tableDrawn > 400) {
    tableDrawn = now;
    renderRobots();
  }
}

function renderRobots() {
  const s = model.snap;
  const waits = new Map();
  for (const w of s.waits) {
    if (!waits.has(w.robot)) waits.set(w.robot, new Set());
    waits.get(w.robot).add(w.for_robot);
  }
  const rows = s.robots.map((r) => {
    const tr = document.createElement("tr");
    tr.dataset.robot = String(r.robot_id);
    tr.dataset.activity = r.activity;
    const cells = [
      `<span class="swatch" style="background:${robotColor(r.robot_id)}"></span>${r.robot_id}`,
      `${r.cell[0]},${r.cell[1]}`, r.connected ? r.activity : "disconnected",
      [...(waits.get(r.robot_id) || [])].join(", "), fmtS(r.slack_ms),
    ];
    tr.innerHTML = cells.map((c) => `<td>${c}</td>`).join("");
    return tr;
  });
  $("robot-rows").replaceChildren(...rows);
}

function renderLog() {
  const items = model.log.slice(0, 30).map((e) => {
    const li = document.createElement("li");
    li.className = e.kind;
    const t = document.createElement("time");
    t.textContent = `${(e.t / 1000).toFixed(1)} s`;
    li.append(t, ` ${e.text}`);
    return li;
  });
  $("log").replaceChildren(...items);
}

function frame() {
  const wall = performance.now();
  if (model.snap) {
    const s = model.snap;
    const now = model.now(wall);
    mapView.draw(model, model.robots(wall), wall);
    chart.draw({
      series: s.fleet_slack, threshold: s.threshold_ms, marks: model.marks, now,
      horizon: s.est_makespan_ms,
      showThreshold: s.policy === "slack" || s.policy === "informed",
    });
    const last = s.fleet_slack.length ? s.fleet_slack[s.fleet_slack.length - 1][1] : 0;
    $("slack-now").textContent = s.plan === null ? "" : `now ${fmtS(last)}`;
    $("clock").textContent = s.plan === null ? "–" : `${(now / 1000).toFixed(1)} s`;
  }
  if (logDirty && wall - logDrawn > 250) {
    logDirty = false;
    logDrawn = wall;
    renderLog();
  }
  requestAnimationFrame(frame);
}

// Keep the picture fresh: while a run is live a snapshot every 250 ms per 60 robots (at most
// every 2 s: a big fleet's snapshot is large, and the events move its robots in between),
// every 2 s otherwise.
setInterval(() => {
  if (!conn.connected) return;
  const robots = model.snap ? model.snap.robots.length : 0;
  const live = model.active || model.status === "planning";
  const every = live ? Math.min(2000, 250 * Math.max(1, robots / 60)) : 2000;
  if (performance.now() - (model.anchorWall || 0) >= every) askSnapshot();
}, 250);

// For tests and the curious: the GUI's view of the fleet.
window.fleetgate = {
  model,
  /** The task board of a lifelong shift (its tasks, finish times and chart bars). */
  tasks: taskBoard,
  status: () => model.status,
  plan: () => (model.snap ? model.snap.plan : null),
  robots: () => model.robots().map((r) => ({
    id: r.id, cell: r.cell, pos: r.pos, activity: r.activity, remaining: r.remaining,
    heading: r.heading, angle: r.angle, turning: r.turning, connected: r.connected,
    paused: r.paused, task: r.task, errands: r.errands,
  })),
  /** What the map last drew per robot: canvas centre, radius, heading angle, turning,
   * connected, paused. */
  drawn: () => mapView.drawn || [],
  /** The errand cells the map last drew (lifelong): robot, task, cell, next, canvas x/y. */
  drawnErrands: () => mapView.drawnErrands || [],
  slack: () => (model.snap ? model.snap.fleet_slack.slice() : []),
  /** The run's clock as the page shows it (plan ms). */
  clock: () => model.now(),
  /** Page coordinates of the centre of cell (x, y) on the map. */
  cellCenter: (x, y) => {
    const box = $("map").getBoundingClientRect();
    const [cx, cy] = mapView.center(x, y);
    return { x: box.left + cx, y: box.top + cy };
  },
};

syncControls();
conn.open();
requestAnimationFrame(frame);
