// The store's objects: a card each with its thumbnail and facts, delete with confirmation.
// Other sections listen for "objects" events to learn the current list.

import * as api from "./api.js";
import { $, el, facts, notice, size, confirmAction } from "./dom.js";

export let list = [];

export function init() {
  $("objects-refresh").addEventListener("click", refresh);
}

export function shown() {
  refresh();
}

// Another key: the same list, with what this key may do.
export function caller() {
  render();
}

export async function refresh() {
  try {
    list = (await api.call("GET", "/v1/objects")).objects;
  } catch (e) {
    notice(`Listing the objects: ${e.message}`);
    return;
  }
  render();
  document.dispatchEvent(new CustomEvent("objects", { detail: list }));
}

function render() {
  $("objects-empty").hidden = list.length > 0;
  $("objects-list").replaceChildren(...list.map(card));
}

function symmetries(s) {
  if (!s) return "unknown";
  const parts = [];
  if (s.continuous.length) parts.push(`turns freely about ${s.continuous.length} axis`);
  if (s.discrete.length) parts.push(`${s.discrete.length} discrete`);
  return `${parts.join(", ") || "none"} (${s.source === "mesh" ? "found from the mesh" : "given"})`;
}

function card(o) {
  const img = el("img", { class: "thumb", alt: `${o.id} drawn from the front right`, width: 160, height: 160 });
  api.imageUrl(`/v1/objects/${encodeURIComponent(o.id)}/thumbnail?size=160&v=${o.created_at}`).then(
    (url) => (img.src = url),
    () => img.classList.add("missing"),
  );
  const remove = el("button", { type: "button", class: "danger", textContent: "Delete", "aria-label": `Delete ${o.id}`, onclick: () => del(o.id) });
  if (!api.can("write") || api.session.caller?.read_only) {
    remove.disabled = true;
    remove.title = api.session.caller?.read_only ? "This server is read-only" : "Your key lacks the write scope";
  }
  return el(
    "li",
    { class: "card", "data-object": o.id },
    img,
    el("h3", {}, o.id),
    facts([
      ["Size", size(o.bytes)],
      ["Templates", String(o.templates)],
      ["Diameter", `${(o.diameter_m * 1000).toFixed(1)} mm`],
      ["Backbone", o.backbone?.name ?? String(o.backbone)],
      ["Symmetries", symmetries(o.symmetries)],
      ["Onboarded", new Date(o.created_at * 1000).toLocaleString()],
    ]),
    remove,
  );
}

async function del(id) {
  if (!(await confirmAction(`Delete ${id} from the store? Estimates will no longer find it.`))) return;
  try {
    await api.call("DELETE", `/v1/objects/${encodeURIComponent(id)}`);
    notice(`Deleted ${id}.`, "ok");
  } catch (e) {
    notice(`Deleting ${id}: ${e.message}`);
  }
  refresh();
}
