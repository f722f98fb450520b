// The operator websocket: protocol v1 envelopes, replies matched to commands, reconnect.

const RETRY_MS = [250, 500, 1000, 2000, 4000];

/** True if this browser holds a live login (the HttpOnly cookie set by `login`). */
export async function loggedIn() {
  const res = await fetch("/session", { credentials: "same-origin", cache: "no-store" });
  return res.ok;
}

/** Log in with an operator token: the gateway checks it and sets an HttpOnly, SameSite=Strict
 * cookie that the operator websocket then carries (the page never keeps the token).
 * Resolves with `{ ok, status, error }` (`error`: the gateway's reason when refused). */
export async function login(token) {
  const res = await fetch("/session", {
    credentials: "same-origin", cache: "no-store",
    headers: { Authorization: `Bearer ${token}` },
  });
  if (res.ok) return { ok: true, status: res.status, error: "" };
  let error = `HTTP ${res.status}`;
  try {
    error = (await res.json()).error || error;
  } catch {
    // not JSON: keep the status
  }
  return { ok: false, status: res.status, error };
}

/** One operator connection to the gateway that reconnects by itself.
 *
 * `onMessage(msg)` gets every snapshot and event; `onLink(state, detail)` gets "on", "off"
 * (it retries) or "refused" (the gateway answered 401/403: it stops retrying).
 * `command(type, fields)` sends a command and resolves with the gateway's `ok` or `error`.
 */
export class Connection {
  constructor(url, { onMessage, onLink }) {
    this.url = url;
    this.onMessage = onMessage;
    this.onLink = onLink;
    this.ws = null;
    this.seq = 0;
    this.prefix = `gui-${Math.random().toString(36).slice(2, 8)}`;
    this.pending = new Map();
    this.failures = 0;
  }

  open() {
    const ws = new WebSocket(this.url);
    this.ws = ws;
    ws.onopen = () => {
      this.failures = 0;
      this.onLink("on", "connected");
    };
    ws.onmessage = (ev) => this.receive(ev.data);
    ws.onclose = async (ev) => {
      this.ws = null;
      for (const [, resolve] of this.pending) resolve({ type: "error", detail: "link lost" });
      this.pending.clear();
      let why = `closed (${ev.code}) ${ev.reason}`;
      if (ev.code === 1006) {
        const refused = await this.refusal();
        if (refused) {
          this.onLink("refused", refused); // retrying with the same token cannot help
          if (!/[?&]token=/.test(this.url)) {
            // no token of its own: back to the login page if the login expired
            loggedIn().then((ok) => ok || location.replace("/login")).catch(() => {});
          }
          return;
        }
        why = "gateway unreachable";
      }
      this.onLink("off", why);
      const delay = RETRY_MS[Math.min(this.failures, RETRY_MS.length - 1)];
      this.failures += 1;
      setTimeout(() => this.open(), delay);
    };
  }

  /** Why the gateway refused the websocket ("403 unknown token"), or null if it did not
   * (a browser does not tell: the same URL fetched over HTTP answers 401/403 with the reason). */
  async refusal() {
    try {
      const resp = await fetch(this.url.replace(/^ws/, "http"), { cache: "no-store" });
      if (resp.status === 401 || resp.status === 403) {
        return `${resp.status} ${(await resp.text()).trim()}`;
      }
    } catch {
      // unreachable: no answer at all
    }
    return null;
  }

  get connected() {
    return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
  }

  receive(text) {
    let msg;
    try {
      msg = JSON.parse(text);
    } catch {
      return;
    }
    if ((msg.type === "ok" || msg.type === "error") && this.pending.has(msg.ref)) {
      const resolve = this.pending.get(msg.ref);
      this.pending.delete(msg.ref);
      resolve(msg);
      return;
    }
    this.onMessage(msg);
  }

  /** Send one message; returns its msg_id (or null when offline). */
  send(type, fields = {}) {
    if (!this.connected) return null;
    const seq = this.seq++;
    const msgId = `${this.prefix}-${seq}`;
    this.ws.send(JSON.stringify({ type, v: 1, msg_id: msgId, seq, ...fields }));
    return msgId;
  }

  /** Send a command and wait for its `ok` / `error` reply. */
  command(type, fields = {}) {
    const msgId = this.send(type, fields);
    if (msgId === null) return Promise.resolve({ type: "error", detail: "not connected" });
    return new Promise((resolve) => this.pending.set(msgId, resolve));
  }
}
