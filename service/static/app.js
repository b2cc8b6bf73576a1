// The page's client of the posedesc API: recognise a frame (a point clicked, or every object found),
// register a mesh and follow its job, list and delete objects. Plain browser JavaScript, no build step.
// Every error the API answers ({"detail": "..."}) is shown where the user acted; text from the service
// (object names, messages) only ever goes in as text (textContent), never as markup.
"use strict";

// The camera of service/examples/ (README: "Try it"), prefilled until the user enters their own.
const EXAMPLE_CAMERA = { fx: 572.4, fy: 573.6, cx: 325.3, cy: 242.0 };
const EXAMPLE_FRAME = { rgb: "robot-rgb.png", depth: "robot-depth.png" };
const EXAMPLE_MESH = "part.ply";
const CAMERA_STORE = "posedesc.camera"; // localStorage: the camera is entered once
const KEY_STORE = "posedesc.apiKey"; // sessionStorage: a secret lives as long as the tab
// A registration's job is polled this often: its progress moves in chunks of views taking about a second.
const POLL_MS = 500;

const $ = (id) => document.getElementById(id);

class ApiError extends Error {
  constructor(status, detail) {
    super(`${status}: ${detail}`);
    this.status = status;
  }
}

// fetch with the API key, turning an error answer into an ApiError carrying the service's message.
async function api(path, options = {}) {
  const headers = new Headers(options.headers || {});
  const key = sessionStorage.getItem(KEY_STORE);
  if (key) headers.set("X-API-Key", key);
  let r;
  try {
    r = await fetch(path, { ...options, headers });
  } catch (e) {
    throw new Error(`the service did not answer (${e.message})`);
  }
  if (r.ok) return r;
  let detail = r.statusText || "error";
  try {
    const body = await r.json();
    detail = typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail ?? body);
  } catch {
    // not JSON (a proxy's page): the status text says what there is to say
  }
  if (r.status === 401 || r.status === 403) askForKey(detail);
  throw new ApiError(r.status, detail);
}

function askForKey(detail) {
  $("key-reason").textContent = `The service refused a write: ${detail}`;
  $("key-section").hidden = false;
}

function say(id, text) {
  $(id).textContent = text;
}

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text;
  row.appendChild(td);
  return td;
}

const fixed = (x, digits = 1) => (typeof x === "number" ? x.toFixed(digits) : "—");

// ---------------------------------------------------------------- recognition

const frame = { rgb: null, depth: null, url: null, example: false };
let asked = 0; // the latest question: an earlier one's late answer is not shown over it
// The objects the last "Find objects" answered: a click inside one's box in a colour frame without depth
// takes its distance. `distanceFound`: the distance field holds such a distance (not one typed).
let found = [];
let distanceFound = false;

function loadCamera() {
  let camera = EXAMPLE_CAMERA;
  try {
    camera = { ...EXAMPLE_CAMERA, ...JSON.parse(localStorage.getItem(CAMERA_STORE) || "{}") };
  } catch {
    // a stored value this page did not write: the examples' camera
  }
  setCamera(camera);
}

function setCamera(camera) {
  for (const name of Object.keys(EXAMPLE_CAMERA)) $(name).value = camera[name] ?? "";
  $("dist_coeffs").value = camera.dist_coeffs ?? "";
  saveCamera();
}

function saveCamera() {
  const camera = { dist_coeffs: $("dist_coeffs").value };
  for (const name of Object.keys(EXAMPLE_CAMERA)) camera[name] = $(name).value;
  localStorage.setItem(CAMERA_STORE, JSON.stringify(camera));
}

// K pasted as OpenCV and BOP write it (cam_K: 9 numbers, row by row) fills fx, fy, cx, cy; anything else
// is said, and the fields keep their values.
function pasteK() {
  const text = $("cam_K").value.trim();
  if (!text) return;
  const k = text.split(/[\s,;\[\]]+/).filter((x) => x !== "").map(Number);
  const ok = k.length === 9 && k.every(Number.isFinite) && k[0] > 0 && k[4] > 0 && k[1] === 0 &&
    k[3] === 0 && k[6] === 0 && k[7] === 0 && k[8] === 1;
  if (!ok) {
    say("camera-note", "K: 9 numbers row by row, fx 0 cx 0 fy cy 0 0 1 (as OpenCV and BOP's cam_K write it).");
    return;
  }
  setCamera({ fx: k[0], fy: k[4], cx: k[2], cy: k[5], dist_coeffs: $("dist_coeffs").value });
  $("cam_K").value = "";
  say("camera-note", "");
  checkCamera();
}

function sameAsExample() {
  return Object.entries(EXAMPLE_CAMERA).every(([n, x]) => Number($(n).value) === x);
}

// A frame of the user's own with the example's camera still in the fields: said, never used silently.
function checkCamera() {
  const own = (frame.rgb || frame.depth) && !frame.example;
  say(
    "camera-note",
    own && sameAsExample()
      ? "These are the example frame's camera values: enter your own camera's fx, fy, cx, cy (or empty them for a patch centred on the object)."
      : "",
  );
}

function setFrame(rgb, depth, example = false) {
  frame.rgb = rgb;
  frame.depth = depth;
  frame.example = example;
  found = [];
  const shown = rgb || depth;
  if (frame.url) URL.revokeObjectURL(frame.url);
  frame.url = shown ? URL.createObjectURL(shown) : null;
  $("frame").hidden = !shown;
  if (shown) $("frame").src = frame.url;
  $("marker").hidden = true;
  const names = [rgb && `colour ${rgb.name}`, depth && `depth ${depth.name}`].filter(Boolean);
  say("frame-files", names.length ? `Frame: ${names.join(", ")}.` : "No frame yet.");
  checkCamera();
  clearAnswers();
}

function clearAnswers() {
  $("answers").tBodies[0].replaceChildren();
  say("answers-note", "");
  say("rec-error", "");
  say("rec-status", "");
  const drawn = $("drawn");
  if (drawn.src.startsWith("blob:")) URL.revokeObjectURL(drawn.src);
  drawn.removeAttribute("src");
  drawn.hidden = true;
  const link = $("download-json");
  if (link.href.startsWith("blob:")) URL.revokeObjectURL(link.href);
  link.removeAttribute("href");
  link.hidden = true;
}

// What the answer area shows, to put back when a question fails: an error does not wipe a good answer.
function keptAnswers() {
  return {
    rows: [...$("answers").tBodies[0].children],
    note: $("answers-note").textContent,
    drawn: $("drawn").hidden ? null : $("drawn").src,
    json: $("download-json").hidden ? null : $("download-json").href,
  };
}

function restoreAnswers(kept) {
  $("answers").tBodies[0].replaceChildren(...kept.rows);
  say("answers-note", kept.note);
  if (kept.drawn) {
    $("drawn").src = kept.drawn;
    $("drawn").hidden = false;
  }
  if (kept.json) {
    $("download-json").href = kept.json;
    $("download-json").hidden = false;
  }
}

// Dropped files: one whose name says "depth" is the depth image, another the colour image.
function dropFrame(files) {
  let { rgb, depth } = frame;
  for (const f of files) {
    if (/depth/i.test(f.name)) depth = f;
    else rgb = f;
  }
  setFrame(rgb, depth);
}

async function exampleFile(name) {
  const r = await api(`/examples/${encodeURIComponent(name)}`);
  return new File([await r.blob()], name, { type: r.headers.get("content-type") || "" });
}

async function loadExampleFrame() {
  try {
    const [rgb, depth] = await Promise.all([exampleFile(EXAMPLE_FRAME.rgb), exampleFile(EXAMPLE_FRAME.depth)]);
    setCamera(EXAMPLE_CAMERA); // the camera the example was taken with
    setFrame(rgb, depth, true);
    say("rec-status", "The example frame and its camera are loaded: click on the robot, or find the objects.");
  } catch (e) {
    say("rec-error", String(e.message));
  }
}

function questionForm(point) {
  const form = new FormData();
  if (frame.rgb) form.append("rgb", frame.rgb, frame.rgb.name || "rgb.png");
  if (frame.depth) form.append("depth", frame.depth, frame.depth.name || "depth.png");
  const fields = Object.fromEntries(Object.keys(EXAMPLE_CAMERA).map((n) => [n, $(n).value]));
  if (point) Object.assign(fields, point);
  fields.dist_coeffs = $("dist_coeffs").value;
  fields.distance_mm = $("distance").value;
  fields.k = $("k").value;
  if (frame.depth) fields.depth_scale = $("depth_scale").value;
  if (!point) {
    fields.min_confidence = $("min_confidence").value;
    fields.max_detections = $("max_detections").value;
  }
  for (const [name, value] of Object.entries(fields)) {
    if (String(value).trim() !== "") form.append(name, String(value).trim());
  }
  return form;
}

// Ask the service about the frame: at a point, or (no point) every object it finds in it. The answer
// and its drawing are asked for together; both are shown once both arrive.
async function ask(point) {
  if (!frame.rgb && !frame.depth) {
    say("rec-error", "Pick a frame first (a colour image, a depth image, or both), or load the example.");
    return;
  }
  if (point && frame.rgb && !frame.depth && !distanceFor(point)) {
    say(
      "rec-error",
      "A colour frame without depth needs the object's distance: enter it (mm), or use Find objects first and click inside an object found.",
    );
    return; // nothing sent, nothing wiped
  }
  const mine = ++asked;
  const kept = keptAnswers();
  clearAnswers();
  say("rec-status", point ? `Asking about (${point.u}, ${point.v}) ...` : "Looking for objects ...");
  try {
    const post = (path) => api(path, { method: "POST", body: questionForm(point) });
    const [answer, drawing] = await Promise.all([post("/recognize"), post("/recognize/draw")]);
    const [body, png] = [await answer.json(), await drawing.blob()];
    if (mine !== asked) return;
    if (kept.drawn?.startsWith("blob:")) URL.revokeObjectURL(kept.drawn);
    if (kept.json?.startsWith("blob:")) URL.revokeObjectURL(kept.json);
    showAnswers(body);
    if (!point) found = foundObjects(body);
    const drawn = $("drawn");
    drawn.src = URL.createObjectURL(png);
    drawn.hidden = false;
    const link = $("download-json");
    link.href = URL.createObjectURL(new Blob([JSON.stringify(body, null, 1)], { type: "application/json" }));
    link.hidden = false;
    const from = distanceFound && point ? ` (distance ${$("distance").value} mm, from the object found there)` : "";
    say("rec-status", `Answered by the ${body.model} model in ${fixed(body.timings_ms?.total, 0)} ms${from}.`);
  } catch (e) {
    if (mine !== asked) return;
    restoreAnswers(kept);
    say("rec-status", "");
    say("rec-error", String(e.message));
  }
}

// The objects of a whole-frame answer: each one's box and distance from the camera, mm.
function foundObjects(body) {
  return (body.detections || [])
    .filter((d) => Array.isArray(d.box) && Array.isArray(d.best?.t))
    .map((d) => ({ box: d.box, distance: Math.round(norm(d.best.t)) }));
}

// The distance to send with a click in a colour frame without depth: the one typed, else that of the
// object found whose box holds the point (filled into the field); none when neither.
function distanceFor(point) {
  const typed = $("distance").value.trim();
  if (typed !== "" && !distanceFound) return typed;
  const [u, v] = [Number(point.u), Number(point.v)];
  const hit = found.find(({ box: [x0, y0, x1, y1] }) => u >= x0 && u <= x1 && v >= y0 && v <= y1);
  if (!hit) return distanceFound ? "" : typed;
  $("distance").value = hit.distance;
  distanceFound = true;
  return String(hit.distance);
}

function norm(t) {
  return Array.isArray(t) ? Math.hypot(...t) : undefined;
}

function answerRow(match, where, note) {
  const row = document.createElement("tr");
  const notes = [note, match.refined ? "fitted" : ""].filter(Boolean).join(", ");
  cell(row, notes ? `${match.name} (${notes})` : match.name);
  cell(row, typeof match.confidence === "number" ? `${Math.round(match.confidence * 100)} %` : "—");
  cell(row, fixed(match.azimuth));
  cell(row, fixed(match.elevation));
  cell(row, fixed(match.inplane));
  cell(row, fixed(norm(match.t), 0));
  cell(row, typeof match.u === "number" ? `(${fixed(match.u, 0)}, ${fixed(match.v, 0)})` : where);
  cell(row, fixed(match.distance, 3));
  return row;
}

function showAnswers(body) {
  const rows = $("answers").tBodies[0];
  if (body.detections) {
    for (const d of body.detections) rows.appendChild(answerRow(d.best, `(${fixed(d.u, 0)}, ${fixed(d.v, 0)})`));
    say("answers-note", body.detections.length ? "Each object found, most confident first." : body.reason || "");
    return;
  }
  const u = $("u").value, v = $("v").value;
  const where = u !== "" && v !== "" ? `(${u}, ${v})` : "patch";
  body.matches.forEach((m, i) => {
    const note = i === 0 ? (body.best ? "best" : "rejected") : "";
    rows.appendChild(answerRow(m, where, note));
  });
  say("answers-note", body.reason ? `No registered object is close enough: ${body.reason}` : "Nearest first.");
}

function pointAt(event) {
  const img = $("frame");
  const box = img.getBoundingClientRect();
  const u = Math.round(((event.clientX - box.left) * img.naturalWidth) / box.width);
  const v = Math.round(((event.clientY - box.top) * img.naturalHeight) / box.height);
  const marker = $("marker");
  marker.style.left = `${event.clientX - box.left}px`;
  marker.style.top = `${event.clientY - box.top}px`;
  marker.hidden = false;
  return { u, v };
}

// ---------------------------------------------------------------- registration

let mesh = null;

function setMesh(file) {
  mesh = file;
  say("mesh-file", file ? `Mesh: ${file.name} (${Math.round(file.size / 1024)} kB).` : "No mesh yet.");
  if (file && $("name").value.trim() === "") $("name").value = file.name.replace(/\.[^.]*$/, "");
}

const wait = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// One bar for the whole registration, in percent: the views rendered and embedded (they overlap: the
// embedding is the later) up to 95 %, storing the templates the rest. Stages count different things (views,
// templates), so the bar never shows a stage's own total, and never moves back.
let registered = 0;

function showProgress(p) {
  const bar = $("reg-progress");
  bar.hidden = false;
  if (!p) {
    registered = 0;
    bar.removeAttribute("value"); // indeterminate until the first chunk of views is done
    say("reg-status", "Registering: starting ...");
    return;
  }
  const share = p.done / Math.max(p.total, 1);
  const part = p.stage === "store" ? 0.95 + 0.05 * share : p.stage === "embed" ? 0.95 * share : 0.9 * share;
  registered = Math.max(registered, part);
  bar.max = 100;
  bar.value = Math.round(100 * registered);
  const unit = p.stage === "store" ? "templates stored" : `views ${p.stage === "embed" ? "embedded" : "rendered"}`;
  say("reg-status", `Registering: ${Math.round(100 * registered)} % (${p.done} of ${p.total} ${unit}) ...`);
}

// A job until it is done (its object) or failed (its error, as POST /objects would have answered it).
async function follow(jobId) {
  for (;;) {
    const job = await (await api(`/jobs/${encodeURIComponent(jobId)}`)).json();
    if (job.status === "done") return job.result;
    if (job.status === "failed") throw new ApiError(job.code ?? 500, job.error || "registration failed");
    showProgress(job.progress);
    await wait(POLL_MS);
  }
}

async function register(event) {
  event.preventDefault();
  say("reg-error", "");
  if (!mesh) {
    say("reg-error", "Pick or drop a mesh file first.");
    return;
  }
  const form = new FormData();
  form.append("mesh", mesh, mesh.name);
  form.append("name", $("name").value.trim());
  form.append("symmetry", $("symmetry").value);
  if ($("units").value) form.append("units", $("units").value);
  $("register").disabled = true;
  showProgress(null);
  try {
    const r = await api("/objects", { method: "POST", body: form });
    const body = await r.json();
    const made = r.status === 202 ? await follow(body.job_id) : body;
    const how = made.symmetry_from === "shape" ? ` Shape only (no colours): symmetry ${made.symmetry}, found from its shape.` : "";
    say("reg-status", `Registered ${made.name} (id ${made.object_id}): ${made.templates} templates in ${fixed(made.seconds)} s.${how}`);
    $("name").value = "";
    await listObjects();
  } catch (e) {
    say("reg-status", "");
    say("reg-error", String(e.message));
  } finally {
    $("reg-progress").hidden = true;
    $("register").disabled = false;
  }
}

// ---------------------------------------------------------------- objects

async function listObjects() {
  say("obj-error", "");
  try {
    const objects = await (await api("/objects")).json();
    const rows = $("objects").tBodies[0];
    rows.replaceChildren(...objects.map(objectRow));
    say("objects-note", objects.length ? "" : "No object is registered yet.");
  } catch (e) {
    say("obj-error", String(e.message));
  }
}

function objectRow(o) {
  const row = document.createElement("tr");
  row.dataset.name = o.name;
  cell(row, String(o.object_id));
  cell(row, o.demo ? `${o.name} (demo)` : o.name);
  cell(row, o.symmetry_from === "shape" ? `${o.symmetry} (shape only)` : o.symmetry);
  cell(row, String(o.faces));
  cell(row, Object.entries(o.templates).map(([m, n]) => `${m} ${n}`).join(", "));
  cell(row, fixed(o.diameter_mm, 0));
  const button = document.createElement("button");
  button.type = "button";
  button.textContent = "Delete";
  button.setAttribute("aria-label", `Delete ${o.name}`);
  button.addEventListener("click", () => deleteObject(o));
  cell(row, "").appendChild(button);
  return row;
}

async function deleteObject(o) {
  if (!confirm(`Delete ${o.name} (id ${o.object_id}) and all its templates? This cannot be undone.`)) return;
  say("obj-error", "");
  try {
    await api(`/objects/${o.object_id}`, { method: "DELETE" });
  } catch (e) {
    say("obj-error", String(e.message));
    return;
  }
  await listObjects();
}

// ---------------------------------------------------------------- wiring

function dropZone(id, onFiles) {
  const zone = $(id);
  zone.addEventListener("dragover", (e) => {
    e.preventDefault();
    zone.classList.add("over");
  });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    if (e.dataTransfer.files.length) onFiles(e.dataTransfer.files);
  });
}

function start() {
  loadCamera();
  for (const input of [...document.querySelectorAll("input.camera"), $("dist_coeffs")]) {
    input.addEventListener("change", () => {
      saveCamera();
      checkCamera();
    });
  }
  $("cam_K").addEventListener("change", pasteK);
  $("distance").addEventListener("input", () => {
    distanceFound = false; // typed: the user's own
  });
  $("rgb").addEventListener("change", (e) => setFrame(e.target.files[0] || null, frame.depth));
  $("depth").addEventListener("change", (e) => setFrame(frame.rgb, e.target.files[0] || null));
  $("clear-depth").addEventListener("click", () => {
    $("depth").value = "";
    setFrame(frame.rgb, null);
  });
  $("example-frame").addEventListener("click", loadExampleFrame);
  dropZone("frame-drop", dropFrame);
  $("frame").addEventListener("click", (e) => {
    const point = pointAt(e);
    $("u").value = point.u;
    $("v").value = point.v;
    ask(point);
  });
  $("ask").addEventListener("click", () => {
    const [u, v] = [$("u").value, $("v").value];
    if (u === "" || v === "") say("rec-error", "Enter u and v, or click on the frame.");
    else ask({ u, v });
  });
  $("find").addEventListener("click", () => ask(null));

  $("mesh").addEventListener("change", (e) => setMesh(e.target.files[0] || null));
  dropZone("mesh-drop", (files) => setMesh(files[0]));
  $("example-mesh").addEventListener("click", async () => {
    try {
      setMesh(await exampleFile(EXAMPLE_MESH));
    } catch (e) {
      say("reg-error", String(e.message));
    }
  });
  $("register-form").addEventListener("submit", register);

  $("key-form").addEventListener("submit", (e) => {
    e.preventDefault();
    sessionStorage.setItem(KEY_STORE, $("api-key").value);
    $("key-reason").textContent = "The key is set: try again.";
  });
  if (sessionStorage.getItem(KEY_STORE)) $("api-key").value = sessionStorage.getItem(KEY_STORE);

  $("refresh").addEventListener("click", listObjects);
  listObjects();
}

document.addEventListener("DOMContentLoaded", start);
