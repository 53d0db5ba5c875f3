// Photos: choose, drop, reorder and check them; the form sent to POST /v1/jobs.
import { $, state, showError } from "./page.js";
import { upload } from "./api.js";
import { follow } from "./job.js";
import { renderThumbs as drawThumbs } from "./thumbs.js";

const MIB = 2 ** 20;
const PHOTO_TYPES = /^image\/(jpeg|png|webp|heic|heif|avif)$/;
const PHOTO_EXTENSIONS = /\.(jpe?g|png|webp|heic|heif|hif|avif)$/i;

// --- photos: choose, take, drop (thumbs.js reorders them) -----------------------------------
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

export function renderCount() {
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

function renderThumbs() {
  drawThumbs(renderThumbs);
  $("submit").disabled = state.photos.length === 0;
  renderCount();
}

export function setUpDropZone() {
  const drop = $("drop");
  ["dragenter", "dragover"].forEach((name) => drop.addEventListener(name, (event) => {
    event.preventDefault();
    drop.classList.add("over");
  }));
  ["dragleave", "drop"].forEach((name) => drop.addEventListener(name, () => drop.classList.remove("over")));
  drop.addEventListener("drop", (event) => { event.preventDefault(); addPhotos(event.dataTransfer.files); });
  $("photos").addEventListener("change", (event) => { addPhotos(event.target.files); event.target.value = ""; });
  // The camera gives one photo a time: each goes after the last, in walking order.
  $("camera").addEventListener("change", (event) => { addPhotos(event.target.files); event.target.value = ""; });
}

// --- submit ----------------------------------------------------------------------------------
function showUploadProgress(fraction) {
  const percent = Math.round(100 * Math.min(1, Math.max(0, fraction)));
  $("upload-progress").hidden = false;
  $("upload-bar").value = percent;
  $("upload-text").textContent = percent < 100 ? `Uploading\u2026 ${percent}%`
    : "Uploaded 100%";
}

export async function submitJob(event) {
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
  if ($("any-order").checked) retrieval.order = "any";
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
