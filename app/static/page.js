// State shared by the page's modules, and the small DOM helpers they all use.

export const $ = (id) => document.getElementById(id);
export const state = {
  photos: [], jobId: null, timer: null, objectUrls: [], info: null,
  pollSeq: 0, failures: 0, failingSince: null, stoppedForAuth: false,
};

export function showError(id, text) {
  const el = $(id);
  el.classList.remove("detailed");
  el.textContent = text || "";
  el.hidden = !text;
}

export function formatDuration(seconds) {
  // "about 40 s", "about 3 min", "about 2.5 h"; "" for no number.
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "";
  const s = Math.max(0, seconds);
  if (s < 90) return `about ${Math.round(s)} s`;
  if (s < 90 * 60) return `about ${Math.round(s / 60)} min`;
  return `about ${Math.round(s / 360) / 10} h`;  // one decimal: 1.5 h, 12 h
}

export function showNotice(text) {
  const el = $("job-notice");
  el.textContent = text || "";
  el.hidden = !text;
}
