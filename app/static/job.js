// Following a job: polling with back-off, the progress bar, queue position and ETA, errors.
import { $, state, formatDuration, showError, showNotice } from "./page.js";
import { api } from "./api.js";
import { showResult } from "./result.js";

const POLL_MS = 1000;                // normal polling interval
const MAX_BACKOFF_S = 30;            // longest wait between retries after failures
const GIVE_UP_MS = 5 * 60 * 1000;    // stop retrying after this long without a good answer

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

export function follow(jobId) {
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
  const text = formatDuration(seconds);
  return text ? `${text} left` : "";
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

export async function cancelJob() {
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
