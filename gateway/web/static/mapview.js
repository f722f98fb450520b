// The map canvas: grid, goals (a lifelong shift: each robot's task errands, the next one
// filled), paths ahead, robots (spanning both cells while moving; grey offline, a pause badge
// while paused), who waits for whom, intruders; and which cell a click hits.

const PALETTE = [
  "#1c7ed6", "#e8590c", "#2b8a3e", "#ae3ec9", "#e67700", "#0c8599", "#d6336c", "#5f3dc4",
  "#66a80f", "#8d5524", "#a61e4d", "#1098ad", "#4c6ef5", "#087f5b", "#be4bdb", "#868e2b",
];

/** The colour of robot `id` (a fixed palette, then golden-angle hues). */
export function robotColor(id) {
  if (id < PALETTE.length) return PALETTE[id];
  return `hsl(${(id * 137.508) % 360}, 62%, 45%)`;
}

const COLORS = {
  free: "#f7f9fb", line: "#dfe5ec", wall: "#3d4654", wait: "#f76707",
  blocked: "#e03131", intruder: "#c92a2a", hover: "rgba(201, 42, 42, 0.35)",
};

export class MapView {
  constructor(canvas, wrap) {
    this.canvas = canvas;
    this.wrap = wrap;
    this.ctx = canvas.getContext("2d");
    this.rows = [];
    this.cell = 10; // px per cell (CSS pixels)
    this.ox = 0;
    this.oy = 0;
    this.hover = null;
    this.dpr = 1;
    this.gridImage = null; // the static map, drawn once per size (large maps stay fast)
    new ResizeObserver(() => this.resize()).observe(wrap);
  }

  setRows(rows) {
    if (rows.length !== this.rows.length || rows.some((r, i) => r !== this.rows[i])) {
      this.rows = rows;
      this.resize();
    }
  }

  get width() {
    return this.rows.length ? this.rows[0].length : 0;
  }

  get height() {
    return this.rows.length;
  }

  resize() {
    const box = this.wrap.getBoundingClientRect();
    const w = Math.max(50, Math.floor(box.width));
    const h = Math.max(50, Math.floor(box.height));
    this.dpr = window.devicePixelRatio || 1;
    this.canvas.width = Math.round(w * this.dpr);
    this.canvas.height = Math.round(h * this.dpr);
    this.canvas.style.width = `${w}px`;
    this.canvas.style.height = `${h}px`;
    if (this.width) {
      this.cell = Math.max(2, Math.min((w - 8) / this.width, (h - 8) / this.height));
      this.ox = (w - this.cell * this.width) / 2;
      this.oy = (h - this.cell * this.height) / 2;
    }
    this.gridImage = null;
  }

  isFree(x, y) {
    return y >= 0 && y < this.height && x >= 0 && x < this.width && this.rows[y][x] === ".";
  }

  /** Canvas CSS-pixel centre of cell (x, y) (fractional cells interpolate). */
  center(x, y) {
    return [this.ox + (x + 0.5) * this.cell, this.oy + (y + 0.5) * this.cell];
  }

  /** The cell under a pointer event, or null. */
  cellAt(ev) {
    const box = this.canvas.getBoundingClientRect();
    const x = Math.floor((ev.clientX - box.left - this.ox) / this.cell);
    const y = Math.floor((ev.clientY - box.top - this.oy) / this.cell);
    return x >= 0 && y >= 0 && x < this.width && y < this.height ? [x, y] : null;
  }

  draw(model, robots, wall) {
    const { ctx } = this;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    if (!this.width) {
      ctx.fillStyle = "#6b7785";
      ctx.font = "16px system-ui, sans-serif";
      ctx.fillText("No instance loaded", 16, 28);
      return;
    }
    if (!this.gridImage) this.gridImage = this.renderGrid();
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(this.gridImage, 0, 0);
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    const s = model.snap;
    this.drawnErrands = [];
    for (const r of robots) {
      if (s.lifelong) this.drawErrands(r);
      else this.drawGoal(r);
    }
    for (const r of robots) this.drawPath(r);
    for (const c of s.intruders) this.drawIntruder(c, wall);
    if (this.hover && this.isFree(...this.hover)) this.drawHover(this.hover);
    for (const r of robots) if (r.to) this.drawSpan(r);
    const byId = new Map(robots.map((r) => [r.id, r]));
    for (const w of s.waits) {
      const a = byId.get(w.robot);
      const b = byId.get(w.for_robot);
      if (a && b) this.drawArrow(a.pos, b.pos);
    }
    this.drawn = [];
    for (const r of robots) this.drawRobot(r);
  }

  renderGrid() {
    const image = document.createElement("canvas");
    image.width = this.canvas.width;
    image.height = this.canvas.height;
    const ctx = image.getContext("2d");
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    const { cell } = this;
    ctx.fillStyle = COLORS.free;
    ctx.fillRect(this.ox, this.oy, cell * this.width, cell * this.height);
    ctx.fillStyle = COLORS.wall;
    for (let y = 0; y < this.height; y += 1) {
      const row = this.rows[y];
      for (let x = 0; x < this.width; x += 1) {
        if (row[x] !== ".") ctx.fillRect(this.ox + x * cell, this.oy + y * cell, cell, cell);
      }
    }
    if (cell >= 6) {
      ctx.strokeStyle = COLORS.line;
      ctx.lineWidth = 1;
      ctx.beginPath();
      for (let x = 0; x <= this.width; x += 1) {
        const px = Math.round(this.ox + x * cell) + 0.5;
        ctx.moveTo(px, this.oy);
        ctx.lineTo(px, this.oy + cell * this.height);
      }
      for (let y = 0; y <= this.height; y += 1) {
        const py = Math.round(this.oy + y * cell) + 0.5;
        ctx.moveTo(this.ox, py);
        ctx.lineTo(this.ox + cell * this.width, py);
      }
      ctx.stroke();
    }
    return image;
  }

  drawGoal(r) {
    const { ctx, cell } = this;
    const [cx, cy] = this.center(r.goal[0], r.goal[1]);
    const h = cell * 0.34;
    ctx.strokeStyle = robotColor(r.id);
    ctx.lineWidth = Math.max(1.5, cell * 0.07);
    ctx.setLineDash([]);
    ctx.strokeRect(cx - h, cy - h, 2 * h, 2 * h);
    if (cell >= 18) {
      ctx.fillStyle = robotColor(r.id);
      ctx.font = `600 ${Math.round(cell * 0.3)}px system-ui, sans-serif`;
      ctx.textAlign = "center";
      ctx.textBaseline = "middle";
      ctx.fillText(String(r.id), cx, cy);
    }
  }

  /** A lifelong robot's task: its errand cells still to reach, the next one filled and
   * outlined boldly, the later ones dashed (numbered in order when cells are large). */
  drawErrands(r) {
    const { ctx, cell } = this;
    const color = robotColor(r.id);
    r.errands.forEach((c, i) => {
      const [cx, cy] = this.center(c[0], c[1]);
      const h = cell * (i === 0 ? 0.4 : 0.3);
      ctx.strokeStyle = color;
      ctx.lineWidth = Math.max(i === 0 ? 2 : 1.2, cell * (i === 0 ? 0.1 : 0.06));
      ctx.setLineDash(i === 0 ? [] : [cell * 0.12, cell * 0.08]);
      if (i === 0) {
        ctx.globalAlpha = 0.3;
        ctx.fillStyle = color;
        ctx.fillRect(cx - h, cy - h, 2 * h, 2 * h);
        ctx.globalAlpha = 1;
      }
      ctx.strokeRect(cx - h, cy - h, 2 * h, 2 * h);
      ctx.setLineDash([]);
      if (cell >= 16) {
        ctx.fillStyle = color;
        ctx.font = `600 ${Math.round(cell * 0.26)}px system-ui, sans-serif`;
        ctx.textAlign = "center";
        ctx.textBaseline = "middle";
        ctx.fillText(`${r.id}·${i + 1}`, cx, cy);
      }
      this.drawnErrands.push({ robot: r.id, task: r.task, cell: c, next: i === 0, x: cx, y: cy });
    });
  }

  drawPath(r) {
    const cells = r.remaining.slice(r.to ? 2 : 1);
    if (!cells.length && !r.to) return;
    const { ctx, cell } = this;
    ctx.strokeStyle = robotColor(r.id);
    ctx.globalAlpha = 0.45;
    ctx.lineWidth = Math.max(1.5, cell * 0.1);
    ctx.lineJoin = "round";
    ctx.lineCap = "round";
    ctx.beginPath();
    ctx.moveTo(...this.center(r.pos[0], r.pos[1]));
    if (r.to) ctx.lineTo(...this.center(r.to[0], r.to[1]));
    for (const c of cells) ctx.lineTo(...this.center(c[0], c[1]));
    ctx.stroke();
    ctx.globalAlpha = 1;
  }

  drawSpan(r) {
    // A moving robot holds both cells: shade the two as one rounded bar.
    const { ctx, cell } = this;
    const x0 = Math.min(r.from[0], r.to[0]);
    const y0 = Math.min(r.from[1], r.to[1]);
    const w = (Math.abs(r.from[0] - r.to[0]) + 1) * cell;
    const h = (Math.abs(r.from[1] - r.to[1]) + 1) * cell;
    const pad = cell * 0.08;
    ctx.fillStyle = robotColor(r.id);
    ctx.globalAlpha = 0.2;
    roundRect(ctx, this.ox + x0 * cell + pad, this.oy + y0 * cell + pad, w - 2 * pad,
      h - 2 * pad, cell * 0.3);
    ctx.fill();
    ctx.globalAlpha = 1;
  }

  drawRobot(r) {
    const { ctx, cell } = this;
    const [cx, cy] = this.center(r.pos[0], r.pos[1]);
    const rad = cell * 0.36;
    ctx.beginPath();
    ctx.arc(cx, cy, rad, 0, 2 * Math.PI);
    ctx.fillStyle = r.connected ? robotColor(r.id) : "#adb5bd";
    ctx.fill();
    ctx.lineWidth = Math.max(1.5, cell * 0.06);
    ctx.strokeStyle = "#ffffff";
    ctx.stroke();
    if (r.activity === "blocked") {
      ctx.beginPath();
      ctx.arc(cx, cy, rad + cell * 0.07, 0, 2 * Math.PI);
      ctx.lineWidth = Math.max(2, cell * 0.09);
      ctx.strokeStyle = COLORS.blocked;
      ctx.stroke();
    }
    if (r.angle !== null && r.angle !== undefined) {
      // the heading: a white wedge at the rim (the id stays readable in the middle); a
      // turning robot also gets a dashed ring
      const a = r.angle;
      ctx.beginPath();
      ctx.moveTo(cx + Math.cos(a) * rad * 1.0, cy + Math.sin(a) * rad * 1.0);
      ctx.lineTo(cx + Math.cos(a + 0.55) * rad * 0.6, cy + Math.sin(a + 0.55) * rad * 0.6);
      ctx.lineTo(cx + Math.cos(a - 0.55) * rad * 0.6, cy + Math.sin(a - 0.55) * rad * 0.6);
      ctx.closePath();
      ctx.fillStyle = "#ffffff";
      ctx.fill();
      if (r.turning) {
        ctx.beginPath();
        ctx.setLineDash([cell * 0.08, cell * 0.08]);
        ctx.arc(cx, cy, rad + cell * 0.07, 0, 2 * Math.PI);
        ctx.lineWidth = Math.max(1.5, cell * 0.05);
        ctx.strokeStyle = robotColor(r.id);
        ctx.stroke();
        ctx.setLineDash([]);
      }
    }
    if (r.paused) { // two bars on a dark badge at the top right
      const b = rad * 0.55;
      const [bx, by] = [cx + rad * 0.7, cy - rad * 0.7];
      ctx.fillStyle = "#343a40";
      ctx.beginPath();
      ctx.arc(bx, by, b, 0, 2 * Math.PI);
      ctx.fill();
      ctx.fillStyle = "#ffffff";
      ctx.fillRect(bx - b * 0.45, by - b * 0.5, b * 0.3, b);
      ctx.fillRect(bx + b * 0.15, by - b * 0.5, b * 0.3, b);
    }
    this.drawn.push({
      id: r.id, x: cx, y: cy, rad, angle: r.angle, turning: r.turning,
      connected: r.connected, paused: r.paused,
    });
    if (cell >= 12) {
      ctx.fillStyle = "#ffffff";
      ctx.font = `700 ${Math.round(cell * 0.34)}px system-ui, sans-serif`;
      ctx.textAlign = "center";
      ctx.textBaseline = "middle";
      ctx.fillText(String(r.id), cx, cy + 0.5);
    }
  }

  drawArrow(from, to) {
    // A curved arrow from the waiting robot to the one it waits for (visible when adjacent).
    const { ctx, cell } = this;
    const [x0, y0] = this.center(from[0], from[1]);
    const [x1, y1] = this.center(to[0], to[1]);
    const len = Math.hypot(x1 - x0, y1 - y0);
    if (len < cell * 0.5) return;
    const bend = Math.max(cell * 0.55, len * 0.22);
    const cx = (x0 + x1) / 2 - ((y1 - y0) / len) * bend;
    const cy = (y0 + y1) / 2 + ((x1 - x0) / len) * bend;
    const gap = cell * 0.42;
    const toward = (px, py, qx, qy) => {
      const d = Math.hypot(qx - px, qy - py);
      return [px + ((qx - px) / d) * gap, py + ((qy - py) / d) * gap];
    };
    const [ax, ay] = toward(x0, y0, cx, cy);
    const [bx, by] = toward(x1, y1, cx, cy);
    const tl = Math.hypot(bx - cx, by - cy);
    const ux = (bx - cx) / tl;
    const uy = (by - cy) / tl;
    const head = Math.max(6, cell * 0.24);
    ctx.strokeStyle = COLORS.wait;
    ctx.fillStyle = COLORS.wait;
    ctx.lineWidth = Math.max(2, cell * 0.08);
    ctx.setLineDash([cell * 0.16, cell * 0.1]);
    ctx.beginPath();
    ctx.moveTo(ax, ay);
    ctx.quadraticCurveTo(cx, cy, bx - ux * head * 0.8, by - uy * head * 0.8);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath();
    ctx.moveTo(bx, by);
    ctx.lineTo(bx - ux * head - uy * head * 0.6, by - uy * head + ux * head * 0.6);
    ctx.lineTo(bx - ux * head + uy * head * 0.6, by - uy * head - ux * head * 0.6);
    ctx.closePath();
    ctx.fill();
  }

  drawIntruder(c, wall) {
    const { ctx, cell } = this;
    const x = this.ox + c[0] * cell;
    const y = this.oy + c[1] * cell;
    const pulse = 0.75 + 0.25 * Math.sin(wall / 180);
    ctx.fillStyle = COLORS.intruder;
    ctx.globalAlpha = pulse;
    roundRect(ctx, x + cell * 0.06, y + cell * 0.06, cell * 0.88, cell * 0.88, cell * 0.14);
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.strokeStyle = "#ffffff";
    ctx.lineWidth = Math.max(2, cell * 0.1);
    ctx.beginPath();
    ctx.moveTo(x + cell * 0.3, y + cell * 0.3);
    ctx.lineTo(x + cell * 0.7, y + cell * 0.7);
    ctx.moveTo(x + cell * 0.7, y + cell * 0.3);
    ctx.lineTo(x + cell * 0.3, y + cell * 0.7);
    ctx.stroke();
  }

  drawHover(c) {
    const { ctx, cell } = this;
    ctx.fillStyle = COLORS.hover;
    ctx.fillRect(this.ox + c[0] * cell, this.oy + c[1] * cell, cell, cell);
  }
}

function roundRect(ctx, x, y, w, h, r) {
  ctx.beginPath();
  ctx.roundRect(x, y, w, h, Math.min(r, w / 2, h / 2));
}
