// State shared by the page's modules, and the small DOM helpers they all use.

export const $ = (id) => document.getElementById(id);
export const state = {
  photos: [], dragFrom: null, jobId: null, timer: null, objectUrls: [], info: null,
  pollSeq: 0, failures: 0, failingSince: null, stoppedForAuth: false,
};

export function showError(id, text) {
  const el = $(id);
  el.classList.remove("detailed");
  el.textContent = text || "";
  el.hidden = !text;
}

export function showNotice(text) {
  const el = $("job-notice");
  el.textContent = text || "";
  el.hidden = !text;
}
