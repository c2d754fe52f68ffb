// Onboarding: the mesh and the files it refers to go up as multipart/form-data; the
// operation is then polled for its progress until it ends, and can be cancelled.

import * as api from "./api.js";
import { $, notice, clearNotice } from "./dom.js";
import { refresh as refreshObjects } from "./objects.js";

let running = null;

export function init() {
  $("onboard-form").addEventListener("submit", (e) => {
    e.preventDefault();
    start();
  });
  $("onboard-cancel").addEventListener("click", cancel);
}

// A key without `write`, or a read-only server: the button cannot work, and says why.
export function caller(c) {
  const why = c.read_only ? "This server is read-only: onboard on its writer." : c.scopes.includes("write") ? "" : `Your key (${c.identity}) lacks the write scope that onboarding needs.`;
  $("onboard-submit").disabled = Boolean(why) || running !== null;
  $("onboard-denied").textContent = why;
  $("onboard-denied").hidden = !why;
}

async function start() {
  clearNotice();
  const form = new FormData();
  const [level, inPlane] = $("onboard-templates").value.split(":");
  form.append("object_id", $("onboard-id").value.trim());
  form.append("units", $("onboard-units").value);
  form.append("level", level);
  form.append("in_plane", inPlane);
  form.append("replace", String($("onboard-replace").checked));
  const mesh = $("onboard-mesh").files[0];
  form.append("mesh", mesh, mesh.name);
  for (const f of $("onboard-resources").files) form.append("resource", f, f.name);
  $("onboard-submit").disabled = true;
  try {
    running = await api.call("POST", "/v1/objects", form);
  } catch (e) {
    notice(`Onboarding: ${e.message}`);
    $("onboard-submit").disabled = false;
    return;
  }
  $("onboard-progress").hidden = false;
  $("onboard-cancel").disabled = false;
  show(running);
  poll();
}

function show(op) {
  const bar = $("onboard-bar");
  bar.max = Math.max(op.templates_total, 1);
  bar.value = op.templates_done;
  const counts = `${op.templates_done} / ${op.templates_total || "?"} templates`;
  $("onboard-state").textContent = {
    running: `Onboarding ${op.object_id}: ${counts}`,
    succeeded: `Onboarded ${op.object_id}: ${op.object?.templates ?? op.templates_total} templates.`,
    failed: `Onboarding ${op.object_id} failed: ${op.error}`,
    cancelled: `Onboarding ${op.object_id} was cancelled.`,
  }[op.state];
  $("onboard-progress").dataset.state = op.state;
}

async function poll() {
  while (running) {
    await new Promise((r) => setTimeout(r, 500));
    let op;
    try {
      op = await api.call("GET", `/v1/operations/${running.id}`);
    } catch (e) {
      notice(`Following the onboarding: ${e.message}`);
      continue;
    }
    show(op);
    if (op.state !== "running") {
      running = null;
      $("onboard-submit").disabled = false;
      $("onboard-cancel").disabled = true;
      if (op.state === "succeeded") refreshObjects();
    }
  }
}

async function cancel() {
  if (!running) return;
  try {
    show(await api.call("POST", `/v1/operations/${running.id}/cancel`));
  } catch (e) {
    notice(`Cancelling: ${e.message}`);
  }
}
