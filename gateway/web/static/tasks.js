// Tasks of a lifelong shift (the task API): the queue, each robot's task and errand, the
// finished tasks and a live throughput chart (tasks finished in each minute of the shift's
// clock; the rate beside the title is the gateway's, the terminal's figure); the operator
// adds, pauses, resumes and cancels tasks. The card stays hidden, and the task API unread,
// until a snapshot says the gateway runs a shift. State: every open task (GET /tasks, page by page), then
// the server-sent events from somewhat before that read: the older ones only give the chart
// and the finished list their recent finishes, the newer ones change the tasks.

const MINUTE = 60000;
const KEEP_ENDED = 50; // finished and cancelled tasks kept for the list
const BARS = 20; // minutes shown by the chart
const REPLAY = 20000; // events read again after a (re)load: about 20 minutes at 500 robots
const OPEN = "queued,paused,assigned,started";
const RECENT = 10; // finished tasks listed

export class TaskBoard {
  /** `onNote(t_ms, text)` gets a line for the event log when a task finishes. */
  constructor(card, onNote = () => {}) {
    this.card = card;
    this.onNote = onNote;
    this.started = false;
    this.fetchDue = false; // a read of the missing tasks is scheduled
    this.perMin = null; // the gateway's tasks per minute of the shift
    this.tasks = new Map(); // id -> TaskView
    this.finishedAt = []; // t_ms of each finish seen (the chart's last BARS minutes)
    this.recent = []; // [task id, t_ms] of the latest finishes, newest first
    this.missing = new Set(); // ids of tasks events named that are not read yet
    this.finished = 0; // tasks finished in the shift (kept by the gateway)
    this.loadedAt = 0; // the last event the task list had seen when it was read
    this.lastEvent = 0;
    this.nowMs = 0;
    this.source = null;
    this.drawPending = false;
    this.$ = (id) => card.querySelector(`#${id}`);
    this.card.addEventListener("click", (e) => this.onClick(e));
  }

  async start() {
    this.started = true;
    this.card.querySelector("#task-form").addEventListener("submit", (e) => this.addTask(e));
    await this.reload();
  }

  /** The gateway's throughput (tasks per minute of the shift so far), from a snapshot. */
  shiftRate(perMin) {
    this.perMin = perMin ?? null;
    this.$("tasks-rate").textContent = this.perMin === null ? ""
      : `${this.perMin.toFixed(1)} / min`;
  }

  /** Submit the form's task (POST /tasks, as a warehouse system would). */
  async addTask(e) {
    e.preventDefault();
    const errands = this.$("task-errands").value.trim().split(/\s+/)
      .map((xy) => xy.split(",").map(Number));
    const note = this.$("tasks-note");
    const r = await fetch("/tasks", {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ errands, priority: Number(this.$("task-priority").value) || 0 }),
    });
    const body = await r.json();
    if (!r.ok) {
      note.textContent = body.error;
      return;
    }
    const task = body.tasks[0];
    this.tasks.set(task.id, task);
    note.textContent = `task ${task.id}: added`;
    this.$("task-errands").value = "";
    this.render();
  }

  /** Read every open task again (first load, and after a `reset` event). */
  async reload() {
    const open = [];
    let first = null;
    let after = -1;
    try {
      do {
        const r = await fetch(`/tasks?state=${OPEN}&limit=1000&after=${after}`,
          { credentials: "same-origin" });
        if (!r.ok) { // 503: not in lifelong mode; anything else: try again later
          this.card.hidden = true;
          setTimeout(() => this.reload(), r.status === 503 ? 10000 : 2000);
          return;
        }
        const body = await r.json();
        first ??= body;
        open.push(...body.tasks);
        after = body.next_after;
      } while (after !== null);
    } catch {
      setTimeout(() => this.reload(), 2000);
      return;
    }
    this.tasks = new Map(open.map((t) => [t.id, t]));
    this.finished = first.counts.finished;
    this.finishedAt = [];
    this.recent = [];
    this.loadedAt = first.last_event; // later events change the tasks read since
    this.lastEvent = Math.max(0, first.last_event - REPLAY);
    this.nowMs = first.now_ms;
    this.card.hidden = false;
    this.listen();
    this.render();
  }

  listen() {
    if (this.source) this.source.close();
    const es = new EventSource(`/tasks/events?after=${this.lastEvent}`);
    es.addEventListener("task", (e) => this.onEvent(JSON.parse(e.data)));
    // events were dropped: reload, unless only some of the replayed ones (the chart's)
    es.addEventListener("reset", () => { if (this.lastEvent >= this.loadedAt) this.reload(); });
    this.source = es;
  }

  onEvent(ev) {
    this.lastEvent = Math.max(this.lastEvent, ev.seq);
    this.nowMs = Math.max(this.nowMs, ev.t_ms);
    if (ev.state === "finished") {
      this.finishedAt.push(ev.t_ms);
      this.recent = [[ev.task, ev.t_ms], ...this.recent.slice(0, RECENT - 1)];
    }
    if (ev.seq <= this.loadedAt) { // replayed: the task list read is newer
      this.scheduleRender();
      return;
    }
    if (ev.state === "finished") {
      this.finished += 1;
      this.onNote(ev.t_ms, `task ${ev.task} finished by robot ${ev.robot ?? "?"}`);
    }
    const t = this.tasks.get(ev.task);
    if (t === undefined) {
      if (ev.state !== "finished" && ev.state !== "cancelled") this.fetchTasks(ev.task);
    } else {
      t.state = ev.state;
      t.robot = ev.robot;
      t.errands_done = ev.errands_done;
    }
    this.scheduleRender();
  }

  /** Read the tasks events name that the board does not know yet (a batch of new ones is
   * read a page at a time, not one request each). */
  fetchTasks(id) {
    this.missing.add(id);
    if (this.fetchDue) return; // a read is due already
    this.fetchDue = true;
    setTimeout(async () => {
      this.fetchDue = false;
      const ids = this.missing;
      this.missing = new Set();
      const low = Math.min(...ids);
      const r = await fetch(`/tasks?after=${low - 1}&limit=1000`, { credentials: "same-origin" });
      if (!r.ok) return;
      const page = await r.json();
      for (const t of page.tasks) {
        if (ids.has(t.id) && !this.tasks.has(t.id)) this.tasks.set(t.id, t);
      }
      if (page.next_after !== null) { // more than a page apart: the rest next time
        for (const rest of ids) if (rest > page.next_after) this.fetchTasks(rest);
      }
      this.scheduleRender();
    }, 100);
  }

  scheduleRender() {
    if (this.drawPending) return;
    this.drawPending = true;
    setTimeout(() => { this.drawPending = false; this.render(); }, 200);
  }

  render() {
    this.finishedAt = this.finishedAt.filter((t) => t > this.nowMs - BARS * MINUTE);
    const all = [...this.tasks.values()];
    const ended = all.filter((t) => t.state === "finished" || t.state === "cancelled")
      .sort((a, b) => (b.finished_ms ?? b.cancelled_ms) - (a.finished_ms ?? a.cancelled_ms));
    for (const t of ended.slice(KEEP_ENDED)) this.tasks.delete(t.id);
    const count = (s) => all.filter((t) => t.state === s).length;
    const held = all.filter((t) => t.state === "assigned" || t.state === "started")
      .sort((a, b) => a.robot - b.robot || (a.assigned_ms ?? 0) - (b.assigned_ms ?? 0)
        || a.id - b.id);
    const byRobot = new Map(); // robot -> its tasks, the one it does now first
    for (const t of held) {
      if (!byRobot.has(t.robot)) byRobot.set(t.robot, []);
      byRobot.get(t.robot).push(t);
    }
    this.$("tasks-counts").textContent = `${count("queued")} queued, ${count("paused")} paused, `
      + `${byRobot.size} robots at work, ${this.finished} finished`;
    this.$("tasks-empty").hidden = count("queued") + count("paused") + held.length > 0;
    const queue = all.filter((t) => t.state === "queued" || t.state === "paused")
      .sort((a, b) => b.priority - a.priority || a.id - b.id).slice(0, 30);
    this.$("queue-rows").replaceChildren(...queue.map((t) => row(t, [
      t.id, t.state, t.errands.map((c) => `(${c[0]},${c[1]})`).join(" → "), t.priority,
    ], [t.state === "paused" ? "resume" : "pause", "cancel"])));
    this.$("work-rows").replaceChildren(...[...byRobot.values()].map(([t, ...next]) => row(t, [
      t.robot, t.id, `${t.errands_done + 1} of ${t.errands.length}`,
      next.map((n) => n.id).join(", "),
    ], t.errands_done === 0 ? ["pause", "cancel"] : []))); // started: no longer
    this.$("finished-list").replaceChildren(...this.recent.map(([id, t]) => {
      const li = document.createElement("li");
      li.textContent = `task ${id} finished at ${(t / 1000).toFixed(1)} s`;
      li.dataset.task = id;
      return li;
    }));
    this.drawChart();
  }

  /** Bars: tasks finished in each of the last BARS minutes of plan time. */
  drawChart() {
    const canvas = this.$("tasks-chart");
    const box = canvas.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(120, Math.floor(box.width));
    const h = Math.max(60, Math.floor(box.height));
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    const last = Math.floor(this.nowMs / MINUTE);
    const bars = new Array(BARS).fill(0);
    for (const t of this.finishedAt) {
      const k = BARS - 1 - (last - Math.floor(t / MINUTE));
      if (k >= 0 && k < BARS) bars[k] += 1;
    }
    this.bars = bars;
    const top = Math.max(1, ...bars);
    const bw = (w - 30) / BARS;
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillStyle = "#5f6b7a";
    ctx.fillText(`${top}`, 2, 12);
    ctx.fillText("min", w - 24, h - 4);
    ctx.fillStyle = "#1c7ed6";
    bars.forEach((n, k) => {
      const bh = (n / top) * (h - 22);
      ctx.fillRect(24 + k * bw + 1, h - 16 - bh, Math.max(1, bw - 2), bh);
    });
  }

  async onClick(e) {
    const button = e.target.closest("button[data-act]");
    if (!button) return;
    const id = Number(button.dataset.task);
    const act = button.dataset.act;
    const r = await fetch(act === "cancel" ? `/tasks/${id}` : `/tasks/${id}/${act}`, {
      method: act === "cancel" ? "DELETE" : "POST", credentials: "same-origin",
    });
    const body = await r.json();
    this.$("tasks-note").textContent = r.ok ? `task ${id}: ${act} done` : body.error;
    if (r.ok) this.tasks.set(id, act === "cancel" ? body : body.task);
    this.render();
  }
}

function row(task, cells, actions) {
  const tr = document.createElement("tr");
  tr.dataset.task = task.id;
  tr.dataset.state = task.state;
  for (const c of cells) {
    const td = document.createElement("td");
    td.textContent = String(c);
    tr.append(td);
  }
  const td = document.createElement("td");
  for (const act of actions) {
    const b = document.createElement("button");
    b.type = "button";
    b.dataset.act = act;
    b.dataset.task = task.id;
    b.textContent = act[0].toUpperCase() + act.slice(1);
    td.append(b);
  }
  tr.append(td);
  return tr;
}
