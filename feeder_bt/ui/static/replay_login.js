// The replay UI's login: the dashboard's users file; on success the page
// reloads and the server sends the replay itself.
"use strict";
document.getElementById("login-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const err = document.getElementById("login-error");
  err.textContent = "";
  const body = JSON.stringify({user: document.getElementById("login-user").value,
                               password: document.getElementById("login-password").value});
  try {
    const r = await fetch("/api/login", {method: "POST", body, credentials: "same-origin",
                                         headers: {"Content-Type": "application/json"}});
    const data = await r.json();
    if (r.ok) { location.reload(); return; }
    err.textContent = data.error || `refused (${r.status})`;
  } catch (e) {
    err.textContent = "the replay server did not answer";
  }
});
