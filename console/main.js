// The console's start: tabs (arrow keys move between them), the API key prompt, what the
// key may do, and each section's module.

import * as api from "./api.js";
import { $, notice, clearNotice } from "./dom.js";
import * as objects from "./objects.js";
import * as onboard from "./onboard.js";
import * as photo from "./photo.js";
import * as service from "./service.js";

const sections = { objects, onboard, photo, service };
const names = Object.keys(sections);

function select(name, focus = false) {
  if (!sections[name]) name = "objects";
  for (const n of names) {
    const tab = $(`tab-${n}`);
    tab.setAttribute("aria-selected", String(n === name));
    tab.tabIndex = n === name ? 0 : -1;
    $(n).hidden = n !== name;
  }
  if (focus) $(`tab-${name}`).focus();
  if (location.hash !== `#${name}`) history.replaceState(null, "", `#${name}`);
  clearNotice();
  sections[name].shown?.();
}

function wireTabs() {
  names.forEach((n, i) => {
    const tab = $(`tab-${n}`);
    tab.addEventListener("click", () => select(n));
    tab.addEventListener("keydown", (e) => {
      const step = { ArrowRight: 1, ArrowLeft: -1 }[e.key];
      if (step) select(names[(i + step + names.length) % names.length], true);
      else if (e.key === "Home") select(names[0], true);
      else if (e.key === "End") select(names[names.length - 1], true);
    });
  });
}

// Opens the key prompt (useKey checks what is typed), saying why when there is a reason.
function askKey(reason = "") {
  const d = $("key-dialog");
  if (d.open) return;
  $("key-error").textContent = reason;
  $("key-error").hidden = !reason;
  $("key-input").value = "";
  d.showModal();
}

async function useKey(k) {
  api.setKey(k);
  try {
    await identify();
    $("key-dialog").close();
    select(location.hash.slice(1));
  } catch (e) {
    api.setKey(null);
    $("key-error").textContent = e.status === 401 ? "The server does not know this key." : e.message;
    $("key-error").hidden = false;
  }
}

// Who the key is, shown in the header; the sections adapt to its scopes.
async function identify() {
  const c = await api.whoAmI();
  $("who").textContent = c.keys_required ? `Key ${c.identity}: ${c.scopes.join(", ")}` : "Open server (no API keys)";
  $("change-key").hidden = !c.keys_required;
  document.body.dataset.scopes = c.scopes.join(" ");
  for (const s of Object.values(sections)) s.caller?.(c);
}

async function start() {
  wireTabs();
  api.onUnauthorized(() => askKey(api.key() ? "The server no longer accepts this key." : ""));
  $("key-form").addEventListener("submit", (e) => {
    e.preventDefault();
    useKey($("key-input").value.trim());
  });
  $("key-dialog").addEventListener("cancel", (e) => e.preventDefault());
  $("change-key").addEventListener("click", () => askKey());
  for (const s of Object.values(sections)) s.init?.();
  try {
    await identify();
  } catch (e) {
    // 401 opened the key prompt already; anything else is worth saying.
    if (e.status !== 401) notice(e.message);
    return;
  }
  select(location.hash.slice(1));
}

start();
