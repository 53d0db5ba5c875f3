// The chosen photos as a grid of numbered thumbnails, reordered by pointer (mouse, touch, pen:
// HTML drag and drop never fires on touch screens) or by each thumbnail's move buttons.
import { $, state } from "./page.js";

const DRAG_START_PX = 6;  // a press that moves less is a tap, not a drag

function thumbPlaceholder(fileName) {
  const box = document.createElement("div");
  box.className = "placeholder";
  box.setAttribute("role", "img");
  box.setAttribute("aria-label", fileName);
  box.textContent = fileName;
  return box;
}

function button(className, text, label, onClick) {
  const element = document.createElement("button");
  element.type = "button";
  element.className = className;
  element.textContent = text;
  element.setAttribute("aria-label", label);
  element.title = label;
  element.addEventListener("click", onClick);
  return element;
}

function announce(text) {
  $("order-status").textContent = text;
}

function move(from, to, onChange, focusClass) {
  // Move photo `from` to place `to`, redraw, and keep the keyboard where the photo went.
  if (to < 0 || to >= state.photos.length || to === from) return;
  const [moved] = state.photos.splice(from, 1);
  state.photos.splice(to, 0, moved);
  onChange();
  announce(`${moved.file.name} is now photo ${to + 1} of ${state.photos.length}`);
  if (focusClass) {
    const item = $("thumbs").children[to];
    const target = item.querySelector(`.${focusClass}:not(:disabled)`) || item.querySelector(".move button:not(:disabled)");
    target?.focus();
  }
}

function thumbItem(photo, index, onChange) {
  const count = state.photos.length;
  const number = index + 1;
  const item = document.createElement("li");
  item.dataset.index = String(index);
  const img = document.createElement("img");
  img.src = photo.url;
  img.alt = `Photo ${number}: ${photo.file.name}`;
  img.draggable = false;  // the pointer handlers move it; a native image drag would cancel them
  // Browsers other than Safari cannot show HEIC: a placeholder with the name stands in.
  img.addEventListener("error", () => img.replaceWith(thumbPlaceholder(photo.file.name)));
  const order = document.createElement("span");
  order.className = "order";
  order.setAttribute("aria-hidden", "true");
  order.textContent = String(number);
  const name = document.createElement("div");
  name.className = "name";
  name.textContent = photo.file.name;
  const remove = button("remove", "\u00d7", `Remove photo ${number} (${photo.file.name})`, () => {
    state.photos.splice(index, 1);
    onChange();
    announce(`${photo.file.name} removed`);
    // The keyboard goes to the photo now in its place (or the one before), else the chooser.
    const next = $("thumbs").children[Math.min(index, state.photos.length - 1)];
    (next?.querySelector(".remove") || $("photos")).focus();
  });
  const moves = document.createElement("div");
  moves.className = "move";
  const earlier = button("earlier", "\u25c0", `Move photo ${number} earlier`,
    () => move(index, index - 1, onChange, "earlier"));
  const later = button("later", "\u25b6", `Move photo ${number} later`,
    () => move(index, index + 1, onChange, "later"));
  earlier.disabled = index === 0;
  later.disabled = index === count - 1;
  moves.append(earlier, later);
  item.append(img, order, name, remove, moves);
  item.addEventListener("pointerdown", (event) => startDrag(event, item, index, onChange));
  return item;
}

function targetIndex(x, y, dragged, home) {
  // The place under (x, y), else the nearest one. The dragged thumbnail follows the pointer, so
  // its own place is where it started (`home`), not where it is drawn.
  let best = dragged, bestDistance = Infinity;
  [...$("thumbs").children].forEach((item, index) => {
    const box = index === dragged ? home : item.getBoundingClientRect();
    const dx = Math.max(box.left - x, 0, x - box.right), dy = Math.max(box.top - y, 0, y - box.bottom);
    const distance = Math.hypot(dx, dy);
    if (distance < bestDistance) { best = index; bestDistance = distance; }
  });
  return best;
}

function startDrag(event, item, index, onChange) {
  if (!event.isPrimary || event.button !== 0 || event.target.closest("button")) return;
  const start = { x: event.clientX, y: event.clientY };
  const home = item.getBoundingClientRect();
  let dragging = false, target = index;
  item.setPointerCapture(event.pointerId);
  const items = () => [...$("thumbs").children];
  const onMove = (moveEvent) => {
    const dx = moveEvent.clientX - start.x, dy = moveEvent.clientY - start.y;
    if (!dragging && Math.hypot(dx, dy) < DRAG_START_PX) return;
    dragging = true;
    item.classList.add("dragging");
    item.style.transform = `translate(${dx}px, ${dy}px)`;
    target = targetIndex(moveEvent.clientX, moveEvent.clientY, index, home);
    items().forEach((other, i) => other.classList.toggle("drop-target", i === target && i !== index));
  };
  const finish = (endEvent) => {
    item.removeEventListener("pointermove", onMove);
    item.removeEventListener("pointerup", finish);
    item.removeEventListener("pointercancel", finish);
    item.classList.remove("dragging");
    item.style.transform = "";
    items().forEach((other) => other.classList.remove("drop-target"));
    if (dragging && endEvent.type === "pointerup") move(index, target, onChange, null);
  };
  item.addEventListener("pointermove", onMove);
  item.addEventListener("pointerup", finish);
  item.addEventListener("pointercancel", finish);
}

export function renderThumbs(onChange) {
  // Draw the thumbnails of state.photos; `onChange` runs after any reorder or removal.
  $("thumbs").replaceChildren(...state.photos.map((photo, index) => thumbItem(photo, index, onChange)));
}
