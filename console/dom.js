// Small DOM helpers shared by the console's modules.

export const $ = (id) => document.getElementById(id);

// An element with attributes (`class`, `for`, data-*, aria-*, properties such as
// `textContent`, `hidden`, `disabled`; `on*` functions become listeners) and children
// (nodes or text).
export function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") e.addEventListener(k.slice(2), v);
    else if (k in e && !k.includes("-") && k !== "list") e[k] = v;
    else e.setAttribute(k, v === true ? "" : String(v));
  }
  e.append(...children.flat().filter((c) => c !== null && c !== undefined && c !== false));
  return e;
}

// The page's message line: errors from the API (they name what is wrong) or a note.
export function notice(message, kind = "error") {
  const n = $("notice");
  n.textContent = message;
  n.dataset.kind = kind;
  n.hidden = !message;
}

export function clearNotice() {
  notice("");
}

// Bytes as people read them.
export function size(bytes) {
  if (bytes >= 1e9) return `${(bytes / 1e9).toFixed(2)} GB`;
  if (bytes >= 1e6) return `${(bytes / 1e6).toFixed(1)} MB`;
  if (bytes >= 1e3) return `${(bytes / 1e3).toFixed(0)} kB`;
  return `${bytes} B`;
}

// A definition list from [term, value] pairs.
export function facts(pairs) {
  return el("dl", { class: "facts" }, pairs.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
}

// Asks a yes/no question in the page's own dialog (keyboard: Enter confirms, Esc cancels).
export function confirmAction(question, action = "Delete") {
  const d = $("confirm-dialog");
  $("confirm-text").textContent = question;
  $("confirm-yes").textContent = action;
  d.returnValue = "";
  d.showModal();
  return new Promise((resolve) => d.addEventListener("close", () => resolve(d.returnValue === "yes"), { once: true }));
}

// File bytes as base64 (what the JSON API takes for images and masks).
export async function base64(blob) {
  const bytes = new Uint8Array(await blob.arrayBuffer());
  let text = "";
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}
