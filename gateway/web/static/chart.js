// The live chart of the fleet slack Δ̄F over plan time, with the threshold and replans.

const C = {
  axis: "#8592a3", grid: "#e9edf2", text: "#4a5563", line: "#1c7ed6", fill: "rgba(28,126,214,0.12)",
  threshold: "#e03131", trigger: "#f76707", plan: "#7048e8",
};

/** A "nice" tick step for a span (1, 2, 5 x 10^k). */
function niceStep(span, count) {
  const raw = span / Math.max(1, count);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const f = raw / mag;
  return (f <= 1 ? 1 : f <= 2 ? 2 : f <= 5 ? 5 : 10) * mag;
}

export class SlackChart {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.dpr = 1;
    this.w = 300;
    this.h = 160;
    new ResizeObserver(() => this.resize()).observe(canvas);
  }

  resize() {
    const box = this.canvas.getBoundingClientRect();
    this.dpr = window.devicePixelRatio || 1;
    this.w = Math.max(120, Math.floor(box.width));
    this.h = Math.max(80, Math.floor(box.height));
    this.canvas.width = Math.round(this.w * this.dpr);
    this.canvas.height = Math.round(this.h * this.dpr);
  }

  /** Draw `series` ([t_ms, slack_ms]...), the threshold and `marks` up to plan time `now`. */
  draw({ series, threshold, marks, now, horizon, showThreshold }) {
    const { ctx, w, h } = this;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    const pad = { l: 38, r: 10, t: 10, b: 24 };
    const pw = w - pad.l - pad.r;
    const ph = h - pad.t - pad.b;
    const tMax = Math.max(10000, now, horizon || 0);
    const top = Math.max(showThreshold ? threshold * 1.3 : 0, 1000,
      ...series.map((p) => p[1] * 1.15));
    const X = (t) => pad.l + (t / tMax) * pw;
    const Y = (v) => pad.t + ph - (v / top) * ph;

    ctx.font = "11px system-ui, sans-serif";
    ctx.lineWidth = 1;
    ctx.fillStyle = C.text;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    const ys = niceStep(top / 1000, 4) * 1000;
    for (let v = 0; v <= top; v += ys) {
      ctx.strokeStyle = C.grid;
      ctx.beginPath();
      ctx.moveTo(pad.l, Math.round(Y(v)) + 0.5);
      ctx.lineTo(pad.l + pw, Math.round(Y(v)) + 0.5);
      ctx.stroke();
      ctx.fillText(`${+(v / 1000).toFixed(1)} s`, pad.l - 5, Y(v));
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    const xs = niceStep(tMax / 1000, Math.max(3, Math.floor(pw / 60))) * 1000;
    for (let t = 0; t <= tMax; t += xs) {
      ctx.fillText(`${+(t / 1000).toFixed(1)} s`, X(t), pad.t + ph + 5);
    }
    ctx.strokeStyle = C.axis;
    ctx.beginPath();
    ctx.moveTo(pad.l + 0.5, pad.t);
    ctx.lineTo(pad.l + 0.5, pad.t + ph + 0.5);
    ctx.lineTo(pad.l + pw, pad.t + ph + 0.5);
    ctx.stroke();

    for (const m of marks) {
      ctx.strokeStyle = m.trigger ? C.trigger : C.plan;
      ctx.setLineDash(m.trigger ? [4, 3] : []);
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.moveTo(X(m.t), pad.t);
      ctx.lineTo(X(m.t), pad.t + ph);
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = m.trigger ? C.trigger : C.plan;
      ctx.textAlign = m.trigger ? "right" : "left";
      ctx.textBaseline = "top";
      ctx.fillText(m.trigger ? "replan" : m.label, X(m.t) + (m.trigger ? -3 : 3), pad.t + 1);
    }

    if (series.length) {
      const pts = [];
      let prev = null;
      for (const [t, v] of series) {
        if (prev !== null) pts.push([t, prev]);
        pts.push([t, v]);
        prev = v;
      }
      pts.push([Math.max(now, series[series.length - 1][0]), prev]);
      ctx.beginPath();
      ctx.moveTo(X(pts[0][0]), Y(0));
      for (const [t, v] of pts) ctx.lineTo(X(t), Y(v));
      ctx.lineTo(X(pts[pts.length - 1][0]), Y(0));
      ctx.closePath();
      ctx.fillStyle = C.fill;
      ctx.fill();
      ctx.beginPath();
      pts.forEach(([t, v], i) => (i ? ctx.lineTo(X(t), Y(v)) : ctx.moveTo(X(t), Y(v))));
      ctx.strokeStyle = C.line;
      ctx.lineWidth = 2;
      ctx.stroke();
    }

    if (showThreshold) {
      ctx.strokeStyle = C.threshold;
      ctx.setLineDash([6, 4]);
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.moveTo(pad.l, Y(threshold));
      ctx.lineTo(pad.l + pw, Y(threshold));
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = C.threshold;
      ctx.textAlign = "left";
      ctx.textBaseline = "bottom";
      ctx.fillText(`threshold ${+(threshold / 1000).toFixed(2)} s`, pad.l + 4, Y(threshold) - 2);
    }
  }
}
