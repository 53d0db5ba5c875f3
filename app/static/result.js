// A finished job: orbit video, model, matches table, cameras from above, masks, downloads.
import { $, showNotice } from "./page.js";
import { api, apiKey, artifactUrl } from "./api.js";
import { attachViewer } from "./viewer.js";

const SVG_NS = "http://www.w3.org/2000/svg";

// The result (the job's result.json) names its artifacts; each downloads from its own URL.
function artifactLinks(jobId, names) {
  return Object.fromEntries(names.map((name) => [name, `/v1/jobs/${jobId}/artifacts/${name}`]));
}

// The library silhouette a photo was matched to (none for a discarded photo).
function silhouetteUrl(model, photo) {
  if (photo.discarded || photo.view === null || photo.view === undefined) return null;
  const near = model.perspective === "near" ? "?perspective=near" : "";
  return `/v1/library/${encodeURIComponent(model.id)}/silhouette/${photo.view}${near}`;
}

export async function showResult(jobId) {
  const result = await api(`/v1/jobs/${jobId}/result`);
  const links = artifactLinks(jobId, result.artifacts || []);
  $("result").hidden = false;
  const video = $("orbit");
  if (links["orbit.mp4"]) {
    // Inline, silent and looping: phones play only muted videos by themselves, and without
    // playsinline iOS takes over the whole screen.
    video.muted = true;
    video.playsInline = true;
    video.loop = true;
    video.src = await artifactUrl(links["orbit.mp4"]);
    video.play().catch(() => {});
  }
  attachViewer(links, video).catch((err) => showNotice(`the 3D view could not be shown: ${err.message}`));
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
  plotCameras(result.photos, result.order || []);
  renderMasks(result.photos, links, (photo) => silhouetteUrl(result.model, photo)).catch((err) => showNotice(`the mask pictures could not be loaded: ${err.message}`));
  const list = $("downloads");
  list.replaceChildren();
  for (const [name, url] of Object.entries(links)) {
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

// How each camera was placed (the result's `placement`: the points the photos share, both those
// and the outline, or the outline alone), and how sure the job is of it, in the last column.
const PLACEMENT_TEXT = {
  matches: "points",
  both: "both",
  silhouettes: "outline",
};

function renderMatches(photos) {
  const body = document.querySelector("#matches tbody");
  body.replaceChildren();
  for (const photo of photos) {
    const row = document.createElement("tr");
    if (photo.discarded) row.className = "discarded";
    const fmt = (value, digits, unit = "") => (value === null || value === undefined ? "\u2013" : value.toFixed(digits) + unit);
    const placed = photo.placement ? PLACEMENT_TEXT[photo.placement] || photo.placement : "";
    const sure = photo.confidence === null || photo.confidence === undefined ? "" : ` ${Math.round(photo.confidence * 100)}%`;
    // The stored name is `NNN_<your file's name>`: the page shows the photo by the user's name.
    const cells = [photo.index + 1, photo.name.replace(/^\d{3}_/, ""), fmt(photo.iou, 3),
      fmt(photo.azimuth, 0, "\u00b0"), fmt(photo.elevation, 0, "\u00b0"),
      photo.discarded ? "discarded" : placed + sure];
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
async function renderMasks(photos, links, silhouette) {
  const gallery = $("mask-gallery");
  gallery.replaceChildren();
  const shown = photos.filter((p) => p.overlay);
  $("mask-section").hidden = !shown.length;
  for (const photo of shown) {
    const item = document.createElement("li");
    if (photo.discarded) item.className = "discarded";
    const pair = document.createElement("div");
    pair.className = "pair";
    pair.append(await maskPicture(links[photo.overlay], `Mask of photo ${photo.index + 1} over it`, "overlay"),
      await maskPicture(silhouette(photo),
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

function plotCameras(photos, order) {
  // Top-down view: world x to the right, world z downwards on screen; +Y (up) points at the viewer.
  // A dashed line joins the cameras in the walking order the poses were found in.
  const svg = $("cameras");
  svg.replaceChildren();
  const placed = photos.filter((p) => p.c2w && !p.discarded);
  const radius = Math.max(1.2, ...placed.map((p) => Math.hypot(p.c2w[0][3], p.c2w[2][3])));
  const scale = 1.4 / radius;
  const byName = new Map(placed.map((p) => [p.name, p]));
  const walked = order.map((name) => byName.get(name)).filter(Boolean);
  $("walk-order").textContent = walked.length
    ? `Walking order: ${walked.map((p) => p.index + 1).join(" \u2192 ")}` : "";
  svg.append(svgElement("circle", { cx: 0, cy: 0, r: scale, fill: "#dfe7f7", stroke: "#9fb3d9", "stroke-width": 0.01 }));
  svg.append(svgElement("circle", { cx: 0, cy: 0, r: 0.03, fill: "#2f6fde" }));
  for (const [text, x, y] of [["front (+z)", -0.3, 1.55], ["+x", 1.45, 0.05]]) {
    const label = svgElement("text", { x, y, "font-size": 0.11, fill: "#5b6475" });
    label.textContent = text;
    svg.append(label);
  }
  if (walked.length > 2) {
    const points = walked.map((p) => `${p.c2w[0][3] * scale},${p.c2w[2][3] * scale}`).join(" ");
    svg.append(svgElement("polygon", { points, fill: "none", stroke: "#5b6475",
      "stroke-width": 0.015, "stroke-dasharray": "0.05 0.04" }));
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
