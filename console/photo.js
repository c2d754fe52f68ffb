// Try a photo: the photo on a canvas, a box drawn (or typed) or a mask painted on it, or
// the detector; the camera's intrinsics typed or picked from cameras saved in this
// browser; the answer drawn by the server (options.overlay), its poses, timings and
// hypotheses, the answer as JSON, and the same request as curl and Python.

import * as api from "./api.js";
import { $, el, notice, clearNotice, base64 } from "./dom.js";
import * as snippets from "./snippets.js";
import { list as knownObjects } from "./objects.js";

const CAMERAS = "b2tf.cameras";
const photo = { file: null, image: null, width: 0, height: 0 };
let box = null; // [x, y, w, h] in image pixels
let paint = null; // a canvas of the image's size: the painted mask (opaque where painted)
let drag = null;
let downloadUrl = null;

export function init() {
  $("photo-file").addEventListener("change", loadPhoto);
  $("photo-form").addEventListener("submit", (e) => {
    e.preventDefault();
    estimate();
  });
  $("photo-clear").addEventListener("click", () => {
    setBox(null);
    if (paint) paint.getContext("2d").clearRect(0, 0, paint.width, paint.height);
    draw();
  });
  for (const id of ["photo-box-x", "photo-box-y", "photo-box-w", "photo-box-h"]) $(id).addEventListener("input", boxFromInputs);
  for (const r of document.querySelectorAll('input[name="mode"]')) r.addEventListener("change", modeChanged);
  const canvas = $("photo-canvas");
  canvas.addEventListener("pointerdown", pointerDown);
  canvas.addEventListener("pointermove", pointerMove);
  canvas.addEventListener("pointerup", () => (drag = null));
  canvas.addEventListener("pointercancel", () => (drag = null));
  $("photo-camera").addEventListener("change", pickCamera);
  $("photo-save-camera").addEventListener("click", saveCamera);
  $("photo-camera-file").addEventListener("change", loadCameraFile);
  for (const b of document.querySelectorAll("button.copy")) b.addEventListener("click", () => navigator.clipboard?.writeText($(b.dataset.copy).textContent));
  document.addEventListener("objects", (e) => objectChoices(e.detail));
  listCameras();
  modeChanged();
}

export function shown() {
  objectChoices(knownObjects);
}

const mode = () => document.querySelector('input[name="mode"]:checked').value;

function modeChanged() {
  $("photo-box").querySelectorAll("input").forEach((i) => (i.disabled = mode() !== "box"));
  $("photo-canvas").dataset.mode = mode();
}

// One checkbox per stored object, keeping what was ticked; a lone object is ticked.
function objectChoices(objects) {
  const group = $("photo-objects");
  const checked = new Set([...group.querySelectorAll("input:checked")].map((i) => i.value));
  if (objects.length === 1) checked.add(objects[0].id);
  group.replaceChildren(
    ...objects.map((o) => el("label", { class: "check" }, el("input", { type: "checkbox", value: o.id, checked: checked.has(o.id) }), ` ${o.id}`)),
  );
  if (!objects.length) group.append(el("span", { class: "hint" }, "No objects: onboard one first."));
}

async function loadPhoto() {
  const file = $("photo-file").files[0];
  if (!file) return;
  const image = new Image();
  image.src = URL.createObjectURL(file);
  try {
    await image.decode();
  } catch {
    notice(`${file.name} is not an image this browser can read.`);
    return;
  }
  Object.assign(photo, { file, image, width: image.naturalWidth, height: image.naturalHeight });
  const canvas = $("photo-canvas");
  canvas.width = photo.width;
  canvas.height = photo.height;
  paint = el("canvas", { width: photo.width, height: photo.height });
  // The principal point defaults to the image centre; the focal length must come from
  // the camera (a guess would put the object at a wrong depth).
  if (!$("photo-cx").value) $("photo-cx").value = (photo.width - 1) / 2;
  if (!$("photo-cy").value) $("photo-cy").value = (photo.height - 1) / 2;
  $("photo-canvas-hint").hidden = true;
  setBox(null);
  $("photo-overlay-figure").hidden = true;
  draw();
}

function draw() {
  const canvas = $("photo-canvas");
  const g = canvas.getContext("2d");
  g.clearRect(0, 0, canvas.width, canvas.height);
  if (!photo.image) return;
  g.drawImage(photo.image, 0, 0);
  if (paint) {
    g.globalAlpha = 0.45;
    g.drawImage(paint, 0, 0);
    g.globalAlpha = 1;
  }
  if (box) {
    g.lineWidth = Math.max(2, photo.width / 300);
    g.strokeStyle = "#00e676";
    g.strokeRect(box[0], box[1], box[2], box[3]);
  }
}

// Pointer position in image pixels.
function at(e) {
  const r = $("photo-canvas").getBoundingClientRect();
  return [((e.clientX - r.left) * photo.width) / r.width, ((e.clientY - r.top) * photo.height) / r.height];
}

function pointerDown(e) {
  if (!photo.image || mode() === "detect") return;
  $("photo-canvas").setPointerCapture(e.pointerId);
  drag = at(e);
  if (mode() === "mask") brush(drag, drag);
}

function pointerMove(e) {
  if (!drag) return;
  const p = at(e);
  if (mode() === "mask") {
    brush(drag, p);
    drag = p;
  } else {
    const [x0, y0] = drag;
    setBox([Math.min(x0, p[0]), Math.min(y0, p[1]), Math.abs(p[0] - x0), Math.abs(p[1] - y0)].map(Math.round));
  }
  draw();
}

// A stroke from the last pointer position to this one (pointer events come sparsely
// when the hand moves fast).
function brush(from, to) {
  const g = paint.getContext("2d");
  g.strokeStyle = "#00e676";
  g.lineWidth = Math.max(8, photo.width / 30);
  g.lineCap = "round";
  g.beginPath();
  g.moveTo(...from);
  g.lineTo(...to);
  g.stroke();
}

function setBox(b) {
  box = b && b[2] >= 1 && b[3] >= 1 ? b : null;
  const ids = ["photo-box-x", "photo-box-y", "photo-box-w", "photo-box-h"];
  ids.forEach((id, i) => ($(id).value = box ? box[i] : ""));
}

function boxFromInputs() {
  const v = ["photo-box-x", "photo-box-y", "photo-box-w", "photo-box-h"].map((id) => Number($(id).value));
  box = v.every(Number.isFinite) && v[2] >= 1 && v[3] >= 1 ? v : null;
  draw();
}

// The painted mask as a PNG: white where painted, black elsewhere.
async function maskPng() {
  const out = el("canvas", { width: photo.width, height: photo.height });
  const g = out.getContext("2d");
  const src = paint.getContext("2d").getImageData(0, 0, photo.width, photo.height);
  let any = false;
  for (let i = 0; i < src.data.length; i += 4) {
    const on = src.data[i + 3] > 0;
    any ||= on;
    src.data.fill(on ? 255 : 0, i, i + 3);
    src.data[i + 3] = 255;
  }
  if (!any) return null;
  g.putImageData(src, 0, 0);
  return base64(await new Promise((r) => out.toBlob(r, "image/png")));
}

// --- cameras saved in this browser (localStorage): name -> intrinsics

const cameras = () => JSON.parse(localStorage.getItem(CAMERAS) || "{}");

function listCameras() {
  const select = $("photo-camera");
  select.replaceChildren(el("option", { value: "" }, "(type the intrinsics)"), ...Object.keys(cameras()).map((n) => el("option", { value: n }, n)));
}

function pickCamera() {
  const c = cameras()[$("photo-camera").value];
  if (!c) return;
  for (const k of ["fx", "fy", "cx", "cy"]) $(`photo-${k}`).value = c[k];
}

// The CLI's camera files: {"K": 3×3, "resolution": [h, w]} or BOP's {"cam_K": 9 values}.
async function loadCameraFile() {
  const file = $("photo-camera-file").files[0];
  if (!file) return;
  let k;
  try {
    const c = JSON.parse(await file.text());
    const m = c.cam_K ?? c.K?.flat();
    if (!Array.isArray(m) || m.length !== 9 || !m.every(Number.isFinite)) throw new Error("no K (3×3) or cam_K (9 numbers)");
    k = { fx: m[0], fy: m[4], cx: m[2], cy: m[5] };
  } catch (e) {
    return notice(`${file.name}: not a camera file (${e.message}).`);
  }
  for (const [n, v] of Object.entries(k)) $(`photo-${n}`).value = v;
  clearNotice();
}

function saveCamera() {
  const k = intrinsics();
  if (!k) return notice("Type fx, fy, cx and cy before saving the camera.");
  const name = prompt("Save these intrinsics as:", $("photo-camera").value || "camera");
  if (!name) return;
  localStorage.setItem(CAMERAS, JSON.stringify({ ...cameras(), [name]: k }));
  listCameras();
  $("photo-camera").value = name;
}

function intrinsics() {
  const k = Object.fromEntries(["fx", "fy", "cx", "cy"].map((n) => [n, Number($(`photo-${n}`).value)]));
  const ok = Object.values(k).every(Number.isFinite) && k.fx > 0 && k.fy > 0;
  return ok ? { ...k, width: photo.width, height: photo.height } : null;
}

// --- the estimate

// The verification settings given (left empty: the server's defaults), as API options.
function settings() {
  const given = {};
  for (const input of $("photo-settings").querySelectorAll("[data-option]")) {
    if (input.value === "") continue;
    const kind = input.dataset.type ?? input.type;
    given[input.dataset.option] = kind === "number" ? Number(input.value) : kind === "bool" ? input.value === "true" : input.value;
  }
  return given;
}

async function request() {
  if (!photo.file) throw new Error("Choose a photo first.");
  const k = intrinsics();
  if (!k) throw new Error("Give the camera's intrinsics: fx and fy (positive), cx and cy, in pixels.");
  const ids = [...$("photo-objects").querySelectorAll("input:checked")].map((i) => i.value);
  if (!ids.length) throw new Error("Choose the object(s) to look for.");
  const options = { rrc: $("photo-rrc").checked, verify: $("photo-verify").checked, ...settings(), overlay: true };
  const req = { image: { encoded: await base64(photo.file) }, intrinsics: k, options };
  // An RGB-D camera's depth: each hypothesis is fitted to the measured surface.
  const depth = $("photo-depth").files[0];
  if (depth) {
    const scale = Number($("photo-depth-scale").value);
    if (!(scale > 0)) throw new Error("Give the depth's scale: millimetres per unit (1 for millimetres, 0.1 for tenths).");
    req.depth = { png16: await base64(depth), scale_mm: scale };
  }
  if (mode() === "detect") return { ...req, objects: ids };
  if (ids.length > 1) throw new Error("A box or a mask is one object's: choose one object (or Detect to look for several).");
  if (mode() === "box") {
    if (!box) throw new Error("Draw a box around the object on the photo (or type x, y, w, h).");
    return { ...req, detections: [{ object_id: ids[0], bbox: box }] };
  }
  const mask = paint && (await maskPng());
  if (!mask) throw new Error("Paint over the object on the photo.");
  return { ...req, detections: [{ object_id: ids[0], mask_png: mask }] };
}

async function estimate() {
  const button = $("photo-estimate");
  // Busy from the click on, before the photo and mask are encoded (awaited): a second click
  // in between must not send a second request, and the last answer, hidden until this one
  // comes, must not read as this one's.
  if (button.disabled) return;
  clearNotice();
  button.disabled = true;
  button.textContent = "Estimating…";
  $("photo-form").setAttribute("aria-busy", "true");
  $("photo-result").hidden = true;
  $("photo-overlay-figure").hidden = true;
  try {
    let req;
    try {
      req = await request();
    } catch (e) {
      return notice(e.message);
    }
    show(req, await api.call("POST", "/v1/estimate", req));
  } catch (e) {
    notice(`Estimating: ${e.message}`);
  } finally {
    button.disabled = false;
    button.textContent = "Estimate";
    $("photo-form").removeAttribute("aria-busy");
  }
}

const fixed = (v, n = 1) => (v === null || v === undefined ? "–" : Number(v).toFixed(n));

function show(req, resp) {
  const { overlay_png, ...answer } = resp;
  if (overlay_png) {
    $("photo-overlay").src = `data:image/png;base64,${overlay_png}`;
    $("photo-overlay-figure").hidden = false;
  }
  const found = answer.results.filter((r) => r.pose).length;
  $("photo-summary").textContent = `${found} pose(s) found of ${answer.results.length} result(s) in ${fixed(answer.total_ms, 0)} ms.${answer.reason ? ` ${answer.reason}` : ""}`;
  $("photo-results").tBodies[0].replaceChildren(
    ...answer.results.map((r) =>
      el(
        "tr",
        { "data-object": r.object_id },
        el("td", {}, r.object_id),
        el("td", {}, String(r.instance)),
        el("td", { class: "score" }, fixed(r.score, 3)),
        el("td", {}, fixed(r.confirmation_score, 3)),
        el("td", { class: "t" }, r.pose ? r.pose.t.map((v) => (v * 1000).toFixed(1)).join(", ") : "–"),
        el("td", { class: "q" }, r.pose ? r.pose.quaternion_wxyz.map((v) => v.toFixed(4)).join(", ") : "–"),
        el("td", { class: "runner-up" }, r.runner_up ? `lost by ${fixed(r.runner_up.margin, 3)}, ${fixed(r.runner_up.distance_over_diameter, 2)}·d away` : "–"),
        el("td", { class: "note" }, r.reason ?? note(r)),
      ),
    ),
  );
  timings(answer.results);
  $("photo-diagnostics").textContent = JSON.stringify(answer.results.map((r) => ({ object_id: r.object_id, instance: r.instance, hypotheses: r.diagnostics })), null, 2);
  if (downloadUrl) URL.revokeObjectURL(downloadUrl);
  downloadUrl = URL.createObjectURL(new Blob([JSON.stringify(answer, null, 2)], { type: "application/json" }));
  $("photo-download").href = downloadUrl;
  const files = { photo: photo.file.name, mask: "mask.png", depth: $("photo-depth").files[0]?.name };
  const keyed = Boolean(api.session.caller?.keys_required);
  $("photo-curl").textContent = snippets.curl(req, files, keyed);
  $("photo-python").textContent = snippets.python(req, files, keyed);
  $("photo-result").hidden = false;
}

// The server says when the runner-up nearly won (runner_up.close_call: its margin below
// 0.03, where on generated scenes the answer was right on about three in five instances
// against 24 in 25 above; docs/service.md, "Runner-up").
function note(r) {
  const notes = [];
  if (r.arbitrary_rotation_about_axis) notes.push("turns freely about an axis: any rotation about it is right");
  if (r.runner_up && r.runner_up.close_call) notes.push("a close call: another pose nearly won (look again, or from elsewhere)");
  // With depth: how the kept pose's surface lies on the measured one (the selected mask's
  // hypothesis is the best-scored).
  const kept = (r.diagnostics ?? []).filter((h) => h.refinement?.depth_fit).sort((a, b) => b.score - a.score)[0];
  const fit = kept?.refinement.depth_fit;
  if (fit) {
    const through = fit.free_space_share > 0.05 ? `, ${Math.round(fit.free_space_share * 100)} % seen through` : "";
    notes.push(`depth: ${Math.round(fit.inlier_share * 100)} % of its surface on the measured one, ${fixed(fit.rms_mm, 1)} mm RMS${through}`);
  }
  return notes.join("; ");
}

// One column per result, one row per stage.
function timings(results) {
  const stages = [...new Set(results.flatMap((r) => Object.keys(r.timings_ms ?? {})))];
  const table = $("photo-timings");
  table.tHead.rows[0].replaceChildren(el("th", {}, "Stage"), ...results.map((r) => el("th", {}, `${r.object_id} #${r.instance}`)));
  table.tBodies[0].replaceChildren(...stages.map((s) => el("tr", {}, el("th", { scope: "row" }, s), ...results.map((r) => el("td", {}, fixed(r.timings_ms?.[s]))))));
}
