// CAD-NeRF web page: pick and order photos, submit, follow progress, show the result.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { photos: [], dragFrom: null, jobId: null, timer: null, objectUrls: [] };
const SVG_NS = "http://www.w3.org/2000/svg";

function apiKey() { return $("api-key").value.trim(); }

function authHeaders() {
  const key = apiKey();
  return key ? { Authorization: `Bearer ${key}` } : {};
}

async function api(path, options = {}) {
  const response = await fetch(path, { ...options, headers: { ...authHeaders(), ...(options.headers || {}) } });
  const body = response.headers.get("content-type")?.includes("json") ? await response.json() : null;
  if (!response.ok) {
    const err = body?.error || { message: response.statusText };
    const where = err.photo || err.field;
    const text = `${where ? where + ": " : ""}${err.message}${err.hint ? " (" + err.hint + ")" : ""}`;
    throw Object.assign(new Error(text), { status: response.status });
  }
  return body;
}

function showError(id, text) {
  const el = $(id);
  el.textContent = text || "";
  el.hidden = !text;
}

// --- photos: choose, drop, reorder ---------------------------------------------------------
function addPhotos(files) {
  for (const file of files) {
    if (!/^image\/(jpeg|png|webp)$/.test(file.type)) continue;
    state.photos.push({ file, url: URL.createObjectURL(file) });
  }
  renderThumbs();
}

function renderThumbs() {
  const list = $("thumbs");
  list.replaceChildren();
  state.photos.forEach((photo, index) => {
    const item = document.createElement("li");
    item.draggable = true;
    item.dataset.index = String(index);
    const img = document.createElement("img");
    img.src = photo.url;
    img.alt = photo.file.name;
    const order = document.createElement("span");
    order.className = "order";
    order.textContent = String(index + 1);
    const name = document.createElement("div");
    name.className = "name";
    name.textContent = photo.file.name;
    const remove = document.createElement("button");
    remove.type = "button";
    remove.textContent = "\u00d7";
    remove.title = "Remove";
    remove.addEventListener("click", () => { state.photos.splice(index, 1); renderThumbs(); });
    item.append(img, order, name, remove);
    item.addEventListener("dragstart", () => { state.dragFrom = index; item.classList.add("dragging"); });
    item.addEventListener("dragend", () => item.classList.remove("dragging"));
    item.addEventListener("dragover", (event) => event.preventDefault());
    item.addEventListener("drop", (event) => {
      event.preventDefault();
      event.stopPropagation();
      if (state.dragFrom === null || state.dragFrom === index) return;
      const [moved] = state.photos.splice(state.dragFrom, 1);
      state.photos.splice(index, 0, moved);
      state.dragFrom = null;
      renderThumbs();
    });
    list.append(item);
  });
  $("submit").disabled = state.photos.length === 0;
}

function setUpDropZone() {
  const drop = $("drop");
  ["dragenter", "dragover"].forEach((name) => drop.addEventListener(name, (event) => {
    event.preventDefault();
    drop.classList.add("over");
  }));
  ["dragleave", "drop"].forEach((name) => drop.addEventListener(name, () => drop.classList.remove("over")));
  drop.addEventListener("drop", (event) => { event.preventDefault(); addPhotos(event.dataTransfer.files); });
  $("photos").addEventListener("change", (event) => { addPhotos(event.target.files); event.target.value = ""; });
}

// --- submit and follow -----------------------------------------------------------------------
async function submitJob(event) {
  event.preventDefault();
  showError("form-error", "");
  const form = new FormData();
  state.photos.forEach((photo) => form.append("images", photo.file, photo.file.name));
  for (const mask of $("masks").files) form.append("masks", mask, mask.name);
  form.append("config", JSON.stringify({ preset: $("preset").value }));
  $("submit").disabled = true;
  try {
    const job = await api("/v1/jobs", { method: "POST", body: form });
    follow(job.id);
  } catch (err) {
    showError("form-error", err.message);
  } finally {
    $("submit").disabled = state.photos.length === 0;
  }
}

function follow(jobId) {
  state.jobId = jobId;
  history.replaceState(null, "", `?job=${jobId}`);
  $("status").hidden = false;
  $("result").hidden = true;
  showError("job-error", "");
  clearInterval(state.timer);
  state.timer = setInterval(poll, 1000);
  poll();
}

function formatEta(seconds) {
  if (seconds === null || seconds === undefined) return "";
  if (seconds < 90) return `about ${Math.round(seconds)} s left`;
  return `about ${Math.round(seconds / 60)} min left`;
}

async function poll() {
  let job;
  try {
    job = await api(`/v1/jobs/${state.jobId}`);
  } catch (err) {
    clearInterval(state.timer);
    showError("job-error", err.message);
    return;
  }
  const percent = Math.round(100 * (job.progress || 0));
  $("bar-fill").style.width = `${percent}%`;
  document.querySelector(".bar").setAttribute("aria-valuenow", String(percent));
  const parts = [job.state, job.stage, `${percent}%`, job.state === "running" ? formatEta(job.eta_s) : ""];
  $("status-text").textContent = parts.filter(Boolean).join(" \u00b7 ");
  if (["succeeded", "failed", "cancelled"].includes(job.state)) {
    clearInterval(state.timer);
    $("cancel").hidden = true;
    if (job.state === "succeeded") await showResult(job.id);
    else showError("job-error", job.error || `the job was ${job.state}`);
  } else {
    $("cancel").hidden = false;
  }
}

async function cancelJob() {
  if (!state.jobId) return;
  clearInterval(state.timer);
  try {
    await api(`/v1/jobs/${state.jobId}`, { method: "DELETE" });
    $("status-text").textContent = "cancelled and deleted";
    $("cancel").hidden = true;
  } catch (err) {
    showError("job-error", err.message);
  }
}

// --- result ----------------------------------------------------------------------------------
async function artifactUrl(url) {
  if (!apiKey()) return url;  // plain URLs stream (and seek) directly
  const response = await fetch(url, { headers: authHeaders() });
  const objectUrl = URL.createObjectURL(await response.blob());
  state.objectUrls.push(objectUrl);
  return objectUrl;
}

async function showResult(jobId) {
  const result = await api(`/v1/jobs/${jobId}/result`);
  $("result").hidden = false;
  const video = $("orbit");
  if (result.artifacts["orbit.mp4"]) {
    video.src = await artifactUrl(result.artifacts["orbit.mp4"]);
    video.play().catch(() => {});
  }
  const category = result.model.category ? ` (${result.model.category})` : "";
  $("model").textContent = `Retrieved CAD model: ${result.model.id}${category}`;
  renderMatches(result.photos);
  plotCameras(result.photos);
  const list = $("downloads");
  list.replaceChildren();
  for (const [name, url] of Object.entries(result.artifacts)) {
    const item = document.createElement("li");
    const link = document.createElement("a");
    link.href = url;
    link.textContent = name;
    link.download = name.replace("/", "_");
    link.addEventListener("click", async (event) => {
      if (!apiKey()) return;  // open server: the plain link works
      event.preventDefault();  // a link cannot send the Authorization header: fetch, then save
      const saver = document.createElement("a");
      saver.href = await artifactUrl(url);
      saver.download = link.download;
      saver.click();
    });
    item.append(link);
    list.append(item);
  }
}

function renderMatches(photos) {
  const body = document.querySelector("#matches tbody");
  body.replaceChildren();
  for (const photo of photos) {
    const row = document.createElement("tr");
    if (photo.discarded) row.className = "discarded";
    const fmt = (value, digits, unit = "") => (value === null || value === undefined ? "\u2013" : value.toFixed(digits) + unit);
    const cells = [photo.index + 1, photo.name, fmt(photo.iou, 3), fmt(photo.azimuth, 0, "\u00b0"),
      fmt(photo.elevation, 0, "\u00b0"), photo.discarded ? "discarded" : ""];
    for (const value of cells) {
      const cell = document.createElement("td");
      cell.textContent = String(value);
      row.append(cell);
    }
    body.append(row);
  }
}

function svgElement(name, attributes) {
  const element = document.createElementNS(SVG_NS, name);
  for (const [key, value] of Object.entries(attributes)) element.setAttribute(key, String(value));
  return element;
}

function plotCameras(photos) {
  // Top-down view: world x to the right, world z downwards on screen; +Y (up) points at the viewer.
  const svg = $("cameras");
  svg.replaceChildren();
  const placed = photos.filter((p) => p.c2w && !p.discarded);
  const radius = Math.max(1.2, ...placed.map((p) => Math.hypot(p.c2w[0][3], p.c2w[2][3])));
  const scale = 1.4 / radius;
  svg.append(svgElement("circle", { cx: 0, cy: 0, r: scale, fill: "#dfe7f7", stroke: "#9fb3d9", "stroke-width": 0.01 }));
  svg.append(svgElement("circle", { cx: 0, cy: 0, r: 0.03, fill: "#2f6fde" }));
  for (const [text, x, y] of [["front (+z)", -0.3, 1.55], ["+x", 1.45, 0.05]]) {
    const label = svgElement("text", { x, y, "font-size": 0.11, fill: "#5b6475" });
    label.textContent = text;
    svg.append(label);
  }
  for (const photo of placed) {
    const x = photo.c2w[0][3] * scale, z = photo.c2w[2][3] * scale;
    const fx = photo.c2w[0][2], fz = photo.c2w[2][2];  // OpenCV forward axis = third column
    const norm = Math.hypot(fx, fz) || 1;
    svg.append(svgElement("line", { x1: x, y1: z, x2: x + 0.25 * fx / norm, y2: z + 0.25 * fz / norm,
      stroke: "#1d2330", "stroke-width": 0.02 }));
    svg.append(svgElement("circle", { cx: x, cy: z, r: 0.06, fill: "#2f6fde" }));
    const label = svgElement("text", { x: x + 0.08, y: z - 0.08, "font-size": 0.14, fill: "#1d2330" });
    label.textContent = String(photo.index + 1);
    svg.append(label);
  }
}

// --- start -----------------------------------------------------------------------------------
async function loadInfo() {
  try {
    const info = await api("/v1/info");
    const select = $("preset");
    select.replaceChildren();
    for (const name of info.presets) {
      const option = new Option(name, name, false, name === info.default_preset);
      select.append(option);
    }
    $("photos").title = `${info.min_photos} to ${info.max_photos} photos`;
  } catch (err) {
    if (err.status === 401) {
      document.querySelector("details").open = true;
      showError("form-error", "This server needs an API key: enter it below, then reload.");
    }
  }
}

function start() {
  setUpDropZone();
  $("job-form").addEventListener("submit", submitJob);
  $("cancel").addEventListener("click", cancelJob);
  $("api-key").value = sessionStorage.getItem("cadnerf-key") || "";
  $("api-key").addEventListener("change", () => { sessionStorage.setItem("cadnerf-key", apiKey()); loadInfo(); });
  loadInfo();
  const jobId = new URLSearchParams(location.search).get("job");
  if (jobId && /^[0-9a-f-]{36}$/.test(jobId)) follow(jobId);
}

start();
