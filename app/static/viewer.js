// Turn the reconstruction yourself. Two views, both optional extras of the result:
// - the orbit video becomes drag-to-spin: dragging across it scrubs through the orbit's frames
//   (the rendered frames look better than the mesh), and it is what remains without the viewer;
// - the textured mesh.glb in <model-viewer> (@google/model-viewer), installed from npm by
//   `make setup` into node_modules and served by this server at /vendor/ (never a CDN); with
//   mesh.usdz as its AR model, a phone offers to place the object in the room (AR Quick Look
//   on an iPhone, WebXR or Scene Viewer on Android).
import { artifactUrl } from "./api.js";

const VIEWER_MODULE = "/vendor/model-viewer.js";
const VIEWER_STYLE = "/static/viewer.css";
// One drag across the video's width turns the object once.
const TURNS_PER_WIDTH = 1;

let viewerModule = null;

function loadViewerModule() {
  // Loaded once, on the first result: a page that never shows a result never fetches 1 MB.
  viewerModule ??= import(VIEWER_MODULE).then(() => true, () => false);
  return viewerModule;
}

function addStyle() {
  if (document.querySelector(`link[href="${VIEWER_STYLE}"]`)) return;
  const link = document.createElement("link");
  link.rel = "stylesheet";
  link.href = VIEWER_STYLE;
  document.head.append(link);
}

// Scrub the orbit video by dragging across it; a click without a drag still plays or pauses.
export function enableDragSpin(video) {
  if (video.dataset.dragSpin) return;
  video.dataset.dragSpin = "on";
  video.classList.add("drag-spin");
  let start = null;
  video.addEventListener("pointerdown", (event) => {
    if (!(video.duration > 0) || event.button !== 0) return;
    const box = video.getBoundingClientRect();
    if (event.clientY > box.bottom - 40) return;  // leave the controls bar alone
    start = { x: event.clientX, time: video.currentTime, width: box.width, moved: false };
    video.setPointerCapture(event.pointerId);
  });
  video.addEventListener("pointermove", (event) => {
    if (!start) return;
    const dx = event.clientX - start.x;
    if (!start.moved && Math.abs(dx) < 4) return;
    if (!start.moved) video.pause();
    start.moved = true;
    const duration = video.duration;
    const time = start.time - (dx / start.width) * duration * TURNS_PER_WIDTH;
    video.currentTime = ((time % duration) + duration) % duration;
  });
  const end = () => {
    if (start?.moved) video.dataset.justDragged = "on";  // the click that ends a drag
    start = null;
  };
  video.addEventListener("pointerup", end);
  video.addEventListener("pointercancel", end);
  video.addEventListener("click", (event) => {
    if (video.dataset.justDragged) event.preventDefault();
    delete video.dataset.justDragged;
  });
}

// The textured mesh in <model-viewer>, in a figure placed before the orbit's; nothing when the
// module is not installed on this server or the job has no mesh.
async function showMesh(meshUrl, usdzUrl, orbitFigure) {
  if (!meshUrl || !(await loadViewerModule()) || !customElements.get("model-viewer")) return null;
  document.getElementById("mesh-figure")?.remove();
  const figure = document.createElement("figure");
  figure.id = "mesh-figure";
  const viewer = document.createElement("model-viewer");
  viewer.id = "mesh-viewer";
  viewer.setAttribute("camera-controls", "");
  viewer.setAttribute("touch-action", "pan-y");
  viewer.setAttribute("interaction-prompt", "none");
  viewer.setAttribute("shadow-intensity", "0.7");
  viewer.setAttribute("exposure", "1");
  viewer.setAttribute("alt", "The reconstructed object's textured mesh: drag to turn it");
  viewer.src = await artifactUrl(meshUrl);
  if (usdzUrl) {
    viewer.setAttribute("ar", "");
    viewer.setAttribute("ar-modes", "webxr scene-viewer quick-look");
    viewer.setAttribute("ios-src", await artifactUrl(usdzUrl));
  }
  const caption = document.createElement("figcaption");
  caption.textContent = "Textured mesh: drag to turn it, scroll or pinch to zoom";
  figure.append(viewer, caption);
  orbitFigure.before(figure);
  return viewer;
}

// The hook result.js calls once the orbit video is set: drag-to-spin on the video, the 3D viewer
// beside it when it can be shown.
export async function attachViewer(artifacts, video) {
  addStyle();
  enableDragSpin(video);
  const figure = video.closest("figure");
  const caption = figure?.querySelector("figcaption");
  if (caption && !caption.dataset.dragHint) {
    caption.dataset.dragHint = "on";
    caption.append(" \u2013 drag across it to turn the object");
  }
  if (!figure) return null;
  return showMesh(artifacts["mesh.glb"], artifacts["mesh.usdz"], figure);
}
