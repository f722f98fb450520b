// The login page: the operator token (typed, or in the URL fragment "#token=..." that
// `fleetgate demo` prints; a fragment never reaches a server) is exchanged for an HttpOnly
// session cookie, then the GUI opens.

import { login } from "./connection.js";

const $ = (id) => document.getElementById(id);

function showError(text) {
  const el = $("login-error");
  el.textContent = text;
  el.hidden = !text;
}

async function submit(token) {
  showError("");
  const res = await login(token);
  if (res.ok) {
    location.replace("/");
    return;
  }
  const why = res.status === 403 ? "bad token" : res.status === 401 ? "no token" : "refused";
  showError(`Login refused (${why}): ${res.error}`);
}

$("login-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  submit($("login-token").value.trim());
});

const fromFragment = new URLSearchParams(location.hash.slice(1)).get("token");
if (fromFragment) {
  history.replaceState(null, "", location.pathname); // keep the token out of the history
  submit(fromFragment);
}
