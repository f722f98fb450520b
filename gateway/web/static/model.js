// What the GUI knows about the fleet: the last snapshot, patched by the event stream.

export const ACTION_MS = 1000; // t_x of every action in plan time (DESIGN section 2)
const ACTIVE = new Set(["running", "paused", "replanning"]);

/** "<run>.<plan>.<robot>.<index>" (or without the run) -> [plan, robot, index] (null if
 * absent or malformed). */
export function parseActionId(id) {
  const m = /^(?:[0-9a-z]{1,16}\.)?(\d+)\.(\d+)\.(\d+)$/.exec(id || "");
  return m ? [Number(m[1]), Number(m[2]), Number(m[3])] : null;
}

/** Cost of one path: the last step at which it arrives at its goal for good. */
export function pathCost(path) {
  let t = path.length - 1;
  while (t > 0 && path[t - 1][0] === path[t][0] && path[t - 1][1] === path[t][1]) t -= 1;
  return t;
}

const sameCell = (a, b) => a[0] === b[0] && a[1] === b[1];

/** Compass letter of a plan heading number (0 east, 1 south, 2 west, 3 north). */
export const HEADING_LETTERS = ["E", "S", "W", "N"];
/** Canvas angle (radians, y down) of a compass heading: east 0, south +pi/2. */
export const HEADING_ANGLE = { E: 0, S: Math.PI / 2, W: Math.PI, N: -Math.PI / 2 };

export class FleetModel {
  constructor() {
    this.snap = null; // the last snapshot, patched in place by events
    this.anchorT = 0; // plan time at anchorWall (performance.now() ms)
    this.anchorWall = 0;
    this.starts = new Map(); // robot -> plan time its running action started
    this.marks = []; // {t, label, trigger} replans for the chart (snapshot, then events)
    this.log = []; // newest first: {t, text, kind}
    this.baseline = null; // SOC and makespan of the run's first plan
  }

  get status() {
    return this.snap ? this.snap.status : "empty";
  }

  get active() {
    return ACTIVE.has(this.status);
  }

  /** The present in plan time, extrapolated from the last snapshot. */
  now(wall = performance.now()) {
    if (!this.snap) return 0;
    if (this.status === "done" || !this.active) return this.anchorT;
    return this.anchorT + (wall - this.anchorWall) * (this.snap.speed || 1);
  }

  applySnapshot(s, wall = performance.now()) {
    const prev = this.snap;
    const newRun = !prev || s.t_ms + 500 < this.now(wall) || s.plan === null
      || (prev.plan !== null && s.plan < prev.plan) || s.map_name !== prev.map_name;
    if (newRun) this.starts.clear();
    this.marks = [];
    for (const m of s.replan_marks || []) {
      this.marks.push({ t: m.trigger_ms, label: m.policy, trigger: true });
      if (m.adopted_ms !== null) this.marks.push({ t: m.adopted_ms, label: `plan ${m.plan}` });
    }
    this.snap = s;
    this.anchorT = s.t_ms;
    this.anchorWall = wall;
    for (const r of s.robots) {
      if (r.activity === "running" && !this.starts.has(r.robot_id)) {
        this.starts.set(r.robot_id, s.t_ms); // first seen moving: assume it just began
      } else if (r.activity !== "running") {
        this.starts.delete(r.robot_id);
      }
    }
  }

  note(t, text, kind = "info") {
    this.log.unshift({ t, text, kind });
    if (this.log.length > 60) this.log.length = 60;
  }

  robot(id) {
    return this.snap ? this.snap.robots[id] : undefined;
  }

  /** Index in robot ``id``'s path of the step its action ``action`` makes (a lifelong
   * snapshot's paths start at the robot's next action, ``path_offsets``). */
  step(id, action) {
    return action - ((this.snap.path_offsets || [])[id] || 0);
  }

  /** Patch the snapshot with one event; returns true if the picture changed. */
  applyEvent(e) {
    const s = this.snap;
    if (!s) return false;
    const r = e.robot !== null && e.robot !== undefined ? this.robot(e.robot) : undefined;
    const samePlan = e.plan === s.plan;
    switch (e.event) {
      case "dispatch":
        if (r && samePlan) {
          r.activity = "received";
          r.action_id = `${e.plan}.${e.robot}.${e.action}`;
        }
        return true;
      case "start":
        if (r && samePlan) {
          r.activity = "running";
          r.action_id = `${e.plan}.${e.robot}.${e.action}`;
          this.starts.set(e.robot, e.t_ms);
        }
        return true;
      case "finish":
        if (r && samePlan) {
          const path = s.paths[e.robot];
          const k = this.step(e.robot, e.action) + 1; // a lifelong path may not reach it yet
          if (path && path[k]) {
            r.cell = path[k];
            r.remaining = path.slice(k);
          }
          const heads = (s.headings || [])[e.robot];
          if (heads && heads[k] !== undefined) {
            r.heading = HEADING_LETTERS[heads[k]];
          }
          r.activity = "idle";
          r.action_id = null;
          s.waits = s.waits.filter((w) => w.for_robot !== e.robot || w.for_action !== e.action);
          this.starts.delete(e.robot);
        }
        return true;
      case "blocked":
      case "unblocked":
        if (r && samePlan) r.activity = e.event === "blocked" ? "blocked" : "received";
        if (e.event === "blocked") this.note(e.t_ms, `robot ${e.robot} blocked`, "warn");
        return true;
      case "refused":
        if (r && samePlan) {
          r.activity = "idle";
          r.action_id = null;
        }
        this.note(e.t_ms, `robot ${e.robot} refused action ${e.action}` +
          (e.reason ? `: ${e.reason}` : ""), "warn");
        return true;
      case "cancel":
        if (r) {
          r.activity = "idle";
          r.action_id = null;
          this.starts.delete(e.robot);
        }
        return true;
      case "plan":
        s.plan = e.plan;
        if (e.paths) {
          s.paths = e.paths;
          s.headings = e.headings || [];
          s.robots.forEach((rb, k) => {
            if (e.paths[k]) rb.remaining = e.paths[k];
          });
        }
        if (e.plan > 0) {
          s.replans = Math.max(s.replans, e.plan);
          this.marks.push({ t: e.t_ms, label: `plan ${e.plan}` });
          this.note(e.t_ms, `new plan ${e.plan} adopted`, "plan");
        }
        return true;
      case "trigger":
        this.marks.push({ t: e.t_ms, label: e.policy, trigger: true });
        this.note(e.t_ms, `replan triggered (${e.policy}, fleet slack ${fmtS(e.fleet_slack_ms)})`,
          "warn");
        return true;
      case "reschedule":
        this.note(e.t_ms, `rescheduled: ${e.switches.map(([c, a, b]) =>
          `robot ${a} passes (${c[0]}, ${c[1]}) before robot ${b}`).join("; ")}`, "plan");
        return true;
      case "slack":
        s.fleet_slack.push([e.t_ms, e.fleet_slack_ms]);
        if (s.fleet_slack.length > 3000) s.fleet_slack.shift();
        return true;
      case "intruder": {
        const on = e.state === "on";
        s.intruders = s.intruders.filter((c) => !sameCell(c, e.cell));
        if (on) s.intruders.push(e.cell);
        this.note(e.t_ms, `intruder ${on ? "on" : "off"} [${e.cell}]`, on ? "warn" : "info");
        return true;
      }
      case "summary":
        this.note(e.t_ms, `done: SOC ${fmtS(e.soc_ms)}, makespan ${fmtS(e.makespan_ms)}`,
          "plan");
        return true;
      case "status":
        if (e.status !== s.status) {
          const freshRun = e.status === "running" && (s.status === "loaded" || s.status === "done");
          if (freshRun) {
            this.marks = [];
            s.fleet_slack = [];
            this.anchorT = 0;
            this.anchorWall = performance.now();
          }
          s.status = e.status;
          this.note(e.t_ms, `status ${e.status}`);
        }
        return true;
      case "connection":
        this.note(e.t_ms, `robot ${e.robot} ${e.state === "on" ? "connected" : "disconnected"}`,
          e.state === "on" ? "info" : "warn");
        return true;
      default:
        return false;
    }
  }

  /** Where each robot is drawn now: [{id, cell, from, to, pos:[x,y], progress, angle,
   * turning, ...}]; ``angle`` is where it faces (radians, null without a heading), turned
   * part of the way while a turn runs. */
  robots(wall = performance.now()) {
    const s = this.snap;
    if (!s) return [];
    const now = this.now(wall);
    return s.robots.map((r) => {
      const out = {
        id: r.robot_id, cell: r.cell, pos: [r.cell[0], r.cell[1]], from: r.cell, to: null,
        progress: 0, activity: r.activity, connected: r.connected, goal: r.goal,
        heading: r.heading, slack_ms: r.slack_ms, remaining: r.remaining || [],
        angle: r.heading ? HEADING_ANGLE[r.heading] : null, turning: false,
        task: r.task ?? null, errands: r.errands || [],
        paused: s.status === "paused" && r.activity !== "running",
      };
      const aid = parseActionId(r.action_id);
      const path = s.paths[r.robot_id];
      // a lifelong action id names its segment, not the snapshot's plan
      const k = aid ? this.step(r.robot_id, aid[2]) : -1;
      if (r.activity === "running" && aid && (s.lifelong || aid[0] === s.plan) && path
          && path[k] && path[k + 1]) {
        const from = path[k];
        const to = path[k + 1];
        const t0 = this.starts.has(r.robot_id) ? this.starts.get(r.robot_id) : now;
        const p = Math.max(0, Math.min(0.97, (now - t0) / ACTION_MS));
        out.from = from;
        out.to = sameCell(from, to) ? null : to;
        out.progress = p;
        out.pos = [from[0] + (to[0] - from[0]) * p, from[1] + (to[1] - from[1]) * p];
        const heads = (s.headings || [])[r.robot_id];
        if (heads && heads[k + 1] !== undefined) {
          const [h0, h1] = [heads[k], heads[k + 1]];
          out.heading = HEADING_LETTERS[h0];
          out.angle = HEADING_ANGLE[out.heading];
          if (h0 !== h1) { // a 90-degree turn in place: clockwise (+1) or counter-clockwise
            out.turning = true;
            out.angle += ((h1 - h0 + 4) % 4 === 1 ? 1 : -1) * (Math.PI / 2) * p;
          }
        }
      }
      return out;
    });
  }

  /** SOC and makespan (ms) of the run's first plan (later plans start mid-run). */
  planCosts() {
    const s = this.snap;
    if (s && !s.lifelong && s.paths.length && (s.plan === null || s.plan === 0)) {
      const costs = s.paths.map(pathCost);
      this.baseline = {
        soc: costs.reduce((a, b) => a + b, 0) * ACTION_MS,
        makespan: Math.max(...costs) * ACTION_MS,
      };
    }
    return this.baseline || null;
  }
}

/** Milliseconds as seconds, e.g. "12.3 s". */
export function fmtS(ms) {
  return ms === null || ms === undefined ? "–" : `${(ms / 1000).toFixed(1)} s`;
}
