// Tasks of a lifelong shift (the task API): the queue, each robot's task and errand, the
// finished tasks and a live throughput chart (tasks finished per minute of the gateway's
// clock); the operator pauses, resumes and cancels tasks. The card stays hidden while the
// gateway is not in lifelong mode. State: GET /tasks, then its server-sent events.

const MINUTE = 60000;
const KEEP_ENDED = 50; // finished and cancelled tasks kept for the list
const BARS = 20; // minutes shown by the chart

export class TaskBoard {
  constructor(card) {
    this.card = card;
    this.tasks = new Map(); // id -> TaskView
    this.finishedAt = []; // t_ms of each finish seen
    this.lastEvent = 0;
    this.nowMs = 0;
    this.source = null;
    this.drawPending = false;
    this.$ = (id) => card.querySelector(`#${id}`);
    this.card.addEventListener("click", (e) => this.onClick(e));
  }

  async start() {
    await this.reload();
  }

  /** Read the whole book again (first load, and after a `reset` event). */
  async reload() {
    let r;
    try {
      r = await fetch("/tasks?limit=1000", { credentials: "same-origin" });
    } catch {
      setTimeout(() => this.reload(), 2000);
      return;
    }
    if (!r.ok) { // 503: not in lifelong mode; anything else: try again later
      this.card.hidden = true;
      setTimeout(() => this.reload(), r.status === 503 ? 10000 : 2000);
      return;
    }
    const body = await r.json();
    this.tasks = new Map(body.tasks.map((t) => [t.id, t]));
    this.finishedAt = body.tasks.filter((t) => t.state === "finished").map((t) => t.finished_ms);
    this.lastEvent = body.last_event;
    this.nowMs = body.now_ms;
    this.card.hidden = false;
    this.listen();
    this.render();
  }

  listen() {
    if (this.source) this.source.close();
    const es = new EventSource(`/tasks/events?after=${this.lastEvent}`);
    es.addEventListener("task", (e) => this.onEvent(JSON.parse(e.data)));
    es.addEventListener("reset", () => this.reload());
    this.source = es;
  }

  onEvent(ev) {
    this.lastEvent = Math.max(this.lastEvent, ev.seq);
    this.nowMs = Math.max(this.nowMs, ev.t_ms);
    if (ev.state === "finished") this.finishedAt.push(ev.t_ms);
    const t = this.tasks.get(ev.task);
    if (t === undefined) {
      this.fetchTask(ev.task);
    } else {
      t.state = ev.state;
      t.robot = ev.robot;
      t.errands_done = ev.errands_done;
    }
    this.scheduleRender();
  }

  async fetchTask(id) {
    const r = await fetch(`/tasks/${id}`, { credentials: "same-origin" });
    if (r.ok) {
      this.tasks.set(id, await r.json());
      this.scheduleRender();
    }
  }

  scheduleRender() {
    if (this.drawPending) return;
    this.drawPending = true;
    setTimeout(() => { this.drawPending = false; this.render(); }, 200);
  }

  /** Tasks finished in the minute of plan time up to now. */
  rate() {
    return this.finishedAt.filter((t) => t > this.nowMs - MINUTE).length;
  }

  render() {
    const all = [...this.tasks.values()];
    const ended = all.filter((t) => t.state === "finished" || t.state === "cancelled")
      .sort((a, b) => (b.finished_ms ?? b.cancelled_ms) - (a.finished_ms ?? a.cancelled_ms));
    for (const t of ended.slice(KEEP_ENDED)) this.tasks.delete(t.id);
    const count = (s) => all.filter((t) => t.state === s).length;
    this.$("tasks-counts").textContent = `${count("queued")} queued, ${count("paused")} paused, `
      + `${count("assigned") + count("started")} at work, ${this.finishedAt.length} finished`;
    this.$("tasks-rate").textContent = `${this.rate()} / min`;
    const queue = all.filter((t) => t.state === "queued" || t.state === "paused")
      .sort((a, b) => b.priority - a.priority || a.id - b.id).slice(0, 30);
    this.$("queue-rows").replaceChildren(...queue.map((t) => row(t, [
      t.id, t.state, t.errands.map((c) => `(${c[0]},${c[1]})`).join(" → "), t.priority,
    ], [t.state === "paused" ? "resume" : "pause", "cancel"])));
    const work = all.filter((t) => t.state === "assigned" || t.state === "started")
      .sort((a, b) => a.robot - b.robot);
    this.$("work-rows").replaceChildren(...work.map((t) => row(t, [
      t.robot, t.id, `${t.errands_done + 1} of ${t.errands.length}`,
    ], t.errands_done === 0 ? ["pause", "cancel"] : []))); // started: no longer
    const done = ended.filter((t) => t.state === "finished").slice(0, 10);
    this.$("finished-list").replaceChildren(...done.map((t) => {
      const li = document.createElement("li");
      li.textContent = `task ${t.id} finished at ${(t.finished_ms / 1000).toFixed(1)} s`;
      li.dataset.task = t.id;
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
