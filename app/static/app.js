// CAD-NeRF web page: pick and order photos, submit, follow progress, show the result.
"use strict";

const $ = (id) => document.getElementById(id);
const state = {
  photos: [], dragFrom: null, jobId: null, timer: null, objectUrls: [], info: null,
  pollSeq: 0, failures: 0, failingSince: null, stoppedForAuth: false,
};
const SVG_NS = "http://www.w3.org/2000/svg";
const POLL_MS = 1000;                // normal polling interval
const MAX_BACKOFF_S = 30;            // longest wait between retries after failures
const GIVE_UP_MS = 5 * 60 * 1000;    // stop retrying after this long without a good answer
const MIB = 2 ** 20;
const PHOTO_TYPES = /^image\/(jpeg|png|webp|heic|heif|avif)$/;
const PHOTO_EXTENSIONS = /\.(jpe?g|png|webp|heic|heif|hif|avif)$/i;

function apiKey() { return $("api-key").value.trim(); }

function authHeaders() {
  const key = apiKey();
  return key ? { Authorization: `Bearer ${key}` } : {};
}

function networkError(cause) {
  // A request that got no usable answer (offline, server restarting, proxy cut the connection).
  return Object.assign(new Error("the server cannot be reached"), { network: true, cause });
}

function retryAfterSeconds(value) {
  // `Retry-After` is either a number of seconds or an HTTP date.
  if (!value) return null;
  const seconds = /^\s*\d+\s*$/.test(value) ? Number(value) : (Date.parse(value) - Date.now()) / 1000;
  return Number.isFinite(seconds) ? Math.max(0, seconds) : null;
}

function httpError(status, statusText, body, retryAfter) {
  // The service's JSON error body {"error": {message, field/photo, hint}} as one line.
  const err = body?.error || { message: statusText || `HTTP ${status}` };
  const where = err.photo || err.field;
  const text = `${where ? where + ": " : ""}${err.message}${err.hint ? " (" + err.hint + ")" : ""}`;
  return Object.assign(new Error(text), { status, retryAfter: retryAfterSeconds(retryAfter) });
}

async function api(path, options = {}) {
  let response, body;
  try {
    response = await fetch(path, { ...options, headers: { ...authHeaders(), ...(options.headers || {}) } });
    body = response.headers.get("content-type")?.includes("json") ? await response.json() : null;
  } catch (cause) {
    throw networkError(cause);  // fetch's TypeError, or a body cut off mid-way
  }
  if (!response.ok) {
    throw httpError(response.status, response.statusText, body, response.headers.get("retry-after"));
  }
  return body;
}

function upload(path, form, onProgress) {
  // POST a FormData like api(), but with XMLHttpRequest: fetch cannot report upload progress.
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", path);
    for (const [name, value] of Object.entries(authHeaders())) xhr.setRequestHeader(name, value);
    xhr.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable && event.total > 0) onProgress(event.loaded / event.total);
    });
    xhr.upload.addEventListener("load", () => onProgress(1));
    xhr.addEventListener("load", () => {
      onProgress(1);  // an answer means the body was sent (or refused early)
      let body = null;
      if (xhr.getResponseHeader("content-type")?.includes("json")) {
        try { body = JSON.parse(xhr.responseText); } catch (cause) { reject(networkError(cause)); return; }
      }
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(httpError(xhr.status, xhr.statusText, body, xhr.getResponseHeader("retry-after")));
    });
    xhr.addEventListener("error", () => reject(networkError()));
    xhr.addEventListener("timeout", () => reject(networkError()));
    xhr.addEventListener("abort", () => reject(networkError()));
    xhr.send(form);
  });
}

function showError(id, text) {
  const el = $(id);
  el.classList.remove("detailed");
  el.textContent = text || "";
  el.hidden = !text;
}

// --- photos: choose, drop, reorder ---------------------------------------------------------
function isSupportedPhoto(file) {
  // Some systems report no type at all: then trust the file name's extension.
  return PHOTO_TYPES.test(file.type) || (!file.type && PHOTO_EXTENSIONS.test(file.name));
}

function addPhotos(files) {
  const skipped = [];
  for (const file of files) {
    if (!isSupportedPhoto(file)) { skipped.push(file.name); continue; }
    state.photos.push({ file, url: URL.createObjectURL(file) });
  }
  const note = $("skipped");
  if (skipped.length) {
    const what = skipped.length === 1 ? "1 file was" : `${skipped.length} files were`;
    note.textContent = `${what} not added: ${skipped.join(", ")}. Only JPEG, PNG, WebP, HEIC `
      + "and AVIF photos are accepted: save them as JPEG and add them again.";
  }
  note.hidden = skipped.length === 0;
  renderThumbs();
}

function photoProblem() {
  // What is wrong with the chosen photos for this server's limits (GET /v1/info), or "".
  const info = state.info;
  const count = state.photos.length;
  if (!info) return "";
  if (count < info.min_photos) {
    return `${count} photo${count === 1 ? "" : "s"} chosen: add ${info.min_photos - count} more `
      + `(${info.min_photos} to ${info.max_photos} photos are needed)`;
  }
  if (count > info.max_photos) {
    return `${count} photos chosen: remove ${count - info.max_photos} `
      + `(at most ${info.max_photos} photos per job)`;
  }
  const tooBig = state.photos.filter((p) => p.file.size > info.max_file_mb * MIB).map((p) => p.file.name);
  if (tooBig.length) {
    return `${tooBig.join(", ")}: larger than ${info.max_file_mb} MiB (save a smaller JPEG)`;
  }
  const files = [...state.photos.map((p) => p.file), ...$("masks").files];
  const total = files.reduce((sum, file) => sum + file.size, 0);
  if (total > info.max_total_mb * MIB) {
    return `the photos and masks add up to ${(total / MIB).toFixed(1)} MiB; at most `
      + `${info.max_total_mb} MiB can be sent (save smaller JPEGs)`;
  }
  return "";
}

function renderCount() {
  const info = state.info;
  const count = state.photos.length;
  const problem = count ? photoProblem() : "";
  let text = "";
  if (problem) text = problem;
  else if (count) text = `${count} photo${count === 1 ? "" : "s"} chosen`;
  else if (info) text = `Choose ${info.min_photos} to ${info.max_photos} photos.`;
  $("photo-count").textContent = text;
  $("photo-count").classList.toggle("warning", Boolean(problem));
}

function thumbPlaceholder(fileName) {
  const box = document.createElement("div");
  box.className = "placeholder";
  box.setAttribute("role", "img");
  box.setAttribute("aria-label", fileName);
  box.textContent = fileName;
  return box;
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
    // Browsers other than Safari cannot show HEIC: a placeholder with the name stands in.
    img.addEventListener("error", () => img.replaceWith(thumbPlaceholder(photo.file.name)));
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
  renderCount();
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
function showUploadProgress(fraction) {
  const percent = Math.round(100 * Math.min(1, Math.max(0, fraction)));
  $("upload-progress").hidden = false;
  $("upload-bar").value = percent;
  $("upload-text").textContent = percent < 100 ? `Uploading\u2026 ${percent}%`
    : "Uploaded 100%";
}

async function submitJob(event) {
  event.preventDefault();
  showError("form-error", "");
  const problem = photoProblem();
  if (problem) {
    showError("form-error", problem);
    return;
  }
  const form = new FormData();
  state.photos.forEach((photo) => form.append("images", photo.file, photo.file.name));
  for (const mask of $("masks").files) form.append("masks", mask, mask.name);
  const config = { preset: $("preset").value };
  const retrieval = {};
  const walk = $("walk").value;
  if (walk !== "auto") retrieval.walk = walk;
  const focal = $("focal").value.trim();
  if (focal !== "") retrieval.focal_35mm = Number(focal);
  if (Object.keys(retrieval).length) config.overrides = { retrieval };
  form.append("config", JSON.stringify(config));
  $("submit").disabled = true;
  showUploadProgress(0);
  try {
    const job = await upload("/v1/jobs", form, showUploadProgress);
    follow(job.id);
  } catch (err) {
    $("upload-progress").hidden = true;
    showError("form-error", err.network
      ? "The upload did not reach the server (network error): check the connection and try again."
      : err.message);
  } finally {
    $("submit").disabled = state.photos.length === 0;
  }
}

function stopPolling() {
  clearTimeout(state.timer);
  state.timer = null;
  state.pollSeq += 1;  // answers of polls still in flight are ignored
}

function schedulePoll(delayMs) {
  const seq = state.pollSeq;
  clearTimeout(state.timer);
  state.timer = setTimeout(() => poll(seq), delayMs);
}

function showNotice(text) {
  const el = $("job-notice");
  el.textContent = text || "";
  el.hidden = !text;
}

function follow(jobId) {
  stopPolling();
  state.jobId = jobId;
  state.failures = 0;
  state.failingSince = null;
  state.stoppedForAuth = false;
  history.replaceState(null, "", `?job=${jobId}`);
  $("status").hidden = false;
  $("result").hidden = true;
  showError("job-error", "");
  showNotice("");
  poll(state.pollSeq);
}

function formatEta(seconds) {
  // "about 40 s left", "about 3 min left", "about 2.5 h left"; "" when there is no estimate.
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "";
  const s = Math.max(0, seconds);
  if (s < 90) return `about ${Math.round(s)} s left`;
  if (s < 90 * 60) return `about ${Math.round(s / 60)} min left`;
  const hours = Math.round(s / 360) / 10;  // one decimal: 1.5 h, 12 h
  return `about ${hours} h left`;
}

function queueText(position) {
  // Jobs ahead of this one in the queue (0 = it is next); "" when the server does not say.
  if (position === null || position === undefined || !Number.isFinite(position)) return "";
  if (position <= 0) return "starts next";
  return `${position} job${position === 1 ? "" : "s"} ahead`;
}

function isTransient(err) {
  // Worth retrying: no answer at all, a server-side failure (503 while Redis restarts), rate limits.
  return Boolean(err.network) || err.status >= 500 || err.status === 408 || err.status === 429;
}

function pollFailed(err) {
  if (!isTransient(err)) {
    stopPolling();
    showNotice("");
    if (err.status === 401) {
      state.stoppedForAuth = true;
      document.querySelector("details").open = true;
      showError("job-error", `Stopped following the job: ${err.message}. Enter the API key under `
        + "\u201cOptional: masks, API key\u201d; following resumes when you change it.");
    } else if (err.status === 403) {
      showError("job-error", `Stopped following the job: this API key may not see it (${err.message}).`);
    } else if (err.status === 404) {
      showError("job-error", `Stopped following the job: it does not exist (any more): ${err.message}.`);
    } else {
      showError("job-error", `Stopped following the job: ${err.message}`);
    }
    return;
  }
  state.failures += 1;
  state.failingSince ??= Date.now();
  const reason = err.network ? "the server cannot be reached" : `the server answered ${err.status}`;
  if (Date.now() - state.failingSince >= GIVE_UP_MS) {
    stopPolling();
    showNotice("");
    const minutes = Math.round((Date.now() - state.failingSince) / 60000);
    showError("job-error", `Lost contact with the server for ${minutes} min (${reason}: ${err.message}). `
      + "The job itself may still be running: reload the page to look again.");
    return;
  }
  const backoff = Math.min(MAX_BACKOFF_S, 2 ** state.failures);
  const waitS = err.retryAfter !== null && err.retryAfter !== undefined
    ? Math.min(Math.max(err.retryAfter, 1), 2 * MAX_BACKOFF_S) : backoff;
  showNotice(`Reconnecting\u2026 ${reason}; trying again in ${Math.round(waitS)} s.`);
  schedulePoll(waitS * 1000);
}

async function poll(seq) {
  if (seq !== state.pollSeq) return;  // a newer follow() or a stop took over
  try {
    const job = await api(`/v1/jobs/${state.jobId}`);
    if (seq !== state.pollSeq) return;
    renderStatus(job);
    const terminal = ["succeeded", "failed", "cancelled"].includes(job.state);
    if (job.state === "succeeded") await showResult(job.id);  // may fail: then retried like a poll
    if (seq !== state.pollSeq) return;
    state.failures = 0;
    state.failingSince = null;
    showNotice("");
    if (terminal) {
      stopPolling();
      $("cancel").hidden = true;
      if (job.state === "failed" && job.error_detail) showFailure(job);
      else if (job.state !== "succeeded") showError("job-error", job.error || `the job was ${job.state}`);
    } else {
      $("cancel").hidden = false;
      schedulePoll(POLL_MS);
    }
  } catch (err) {
    if (seq === state.pollSeq) pollFailed(err);
  }
}

function renderStatus(job) {
  const percent = Math.round(100 * (job.progress || 0));
  $("bar-fill").style.width = `${percent}%`;
  document.querySelector(".bar").setAttribute("aria-valuenow", String(percent));
  const parts = job.state === "queued"
    ? [job.state, queueText(job.queue_position), formatEta(job.eta_s)]  // eta_s includes the wait
    : [job.state, job.stage, `${percent}%`, job.state === "running" ? formatEta(job.eta_s) : ""];
  $("status-text").textContent = parts.filter(Boolean).join(" \u00b7 ");
}

function showFailure(job) {
  // A failed job's error_detail: the photo (or field) in bold, the message, "What to do: hint".
  // Built with textContent only: every string here comes from the server (photo = upload name).
  const detail = job.error_detail;
  const el = $("job-error");
  el.replaceChildren();
  const where = detail.photo || detail.field;
  if (where) {
    const name = document.createElement("strong");
    name.className = "where";
    name.textContent = where;
    el.append(name, ": ");
  }
  const message = document.createElement("span");
  message.className = "message";
  message.textContent = detail.message || job.error || "the job failed";
  el.append(message);
  if (detail.hint) {
    const hint = document.createElement("span");
    hint.className = "what-to-do";
    hint.textContent = `What to do: ${detail.hint}`;
    el.append(hint);
  }
  el.classList.add("detailed");
  el.hidden = false;
}

async function cancelJob() {
  if (!state.jobId) return;
  stopPolling();
  showNotice("");
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
  const warnings = $("warnings");
  warnings.replaceChildren(...(result.warnings || []).map((text) => {
    const item = document.createElement("li");
    item.textContent = text;
    return item;
  }));
  warnings.hidden = !warnings.children.length;
  renderMatches(result.photos);
  plotCameras(result.photos);
  renderMasks(result.photos).catch((err) => showNotice(`the mask pictures could not be loaded: ${err.message}`));
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

// How each mask source reads on the page (the API's `mask_source`).
const MASK_SOURCE_TEXT = {
  uploaded: "uploaded (your mask)",
  alpha: "alpha (the photo's transparency)",
  learned: "learned (background removal)",
  grabcut: "grabcut (background removal)",
};

async function maskPicture(url, alt, className) {
  if (!url) {
    const none = document.createElement("span");
    none.className = `${className} missing`;
    none.textContent = "no match";
    return none;
  }
  const image = document.createElement("img");
  image.className = className;
  image.alt = alt;
  image.decoding = "async";
  image.src = await artifactUrl(url);
  return image;
}

// Per photo: the mask it used over the photo, the library silhouette it matched, the mask's
// source and warnings; a badly cut object is seen here, not mistaken for a failure of the method.
async function renderMasks(photos) {
  const gallery = $("mask-gallery");
  gallery.replaceChildren();
  const shown = photos.filter((p) => p.overlay);
  $("mask-section").hidden = !shown.length;
  for (const photo of shown) {
    const item = document.createElement("li");
    if (photo.discarded) item.className = "discarded";
    const pair = document.createElement("div");
    pair.className = "pair";
    pair.append(await maskPicture(photo.overlay, `Mask of photo ${photo.index + 1} over it`, "overlay"),
      await maskPicture(photo.discarded ? null : photo.silhouette,
        `Library silhouette matched to photo ${photo.index + 1}`, "silhouette"));
    const caption = document.createElement("p");
    caption.className = "mask-caption";
    const source = MASK_SOURCE_TEXT[photo.mask_source] || "unknown";
    caption.textContent = `${photo.index + 1}. ${photo.name} \u2013 mask: ${source}`
      + (photo.discarded ? " \u2013 discarded" : "");
    item.append(pair, caption);
    for (const text of photo.mask_warnings || []) {
      const warning = document.createElement("p");
      warning.className = "warning mask-warning";
      warning.textContent = text;
      item.append(warning);
    }
    gallery.append(item);
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
    state.info = info;
    const select = $("preset");
    select.replaceChildren();
    for (const name of info.presets) {
      const option = new Option(name, name, false, name === info.default_preset);
      select.append(option);
    }
    $("photos").title = `${info.min_photos} to ${info.max_photos} photos`;
    renderCount();
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
  $("api-key").addEventListener("change", () => {
    sessionStorage.setItem("cadnerf-key", apiKey());
    loadInfo();
    if (state.stoppedForAuth && state.jobId) follow(state.jobId);  // try again with the new key
  });
  $("masks").addEventListener("change", renderCount);
  loadInfo();
  const jobId = new URLSearchParams(location.search).get("job");
  if (jobId && /^[0-9a-f-]{36}$/.test(jobId)) follow(jobId);
}

start();
