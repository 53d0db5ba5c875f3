// CAD-NeRF web page: pick and order photos, submit, follow progress, show the result.
import { $, state, formatDuration, showError } from "./page.js";
import { api, apiKey } from "./api.js";
import { renderCount, setUpDropZone, submitJob } from "./upload.js";
import { follow, cancelJob } from "./job.js";

const DEVICE_TEXT = { cpu: "without a GPU", cuda: "on a GPU" };

// --- presets and their expected times on this server (GET /v1/info) --------------------------
function presetTime(info, name) {
  // The preset's expected job time as `{ short, long }` text, from the server's ETA table.
  const time = info.preset_times?.[name];
  const duration = formatDuration(time?.seconds);
  if (!duration) return { short: "not measured yet", long: "not measured yet on this server" };
  if (time.measured) return { short: duration, long: `${duration} a job, measured on this server` };
  return { short: duration, long: `${duration} a job (estimate; not measured yet on this server)` };
}

function showPresetTime() {
  const info = state.info;
  const name = $("preset").value;
  if (!info || !name) return;
  const where = DEVICE_TEXT[info.device] ? ` This server runs jobs ${DEVICE_TEXT[info.device]}.` : "";
  $("preset-time").textContent = `${name}: ${presetTime(info, name).long}.${where}`;
}

function fillPresets(info) {
  const select = $("preset");
  select.replaceChildren();
  for (const name of info.presets) {
    const option = new Option(`${name} \u2013 ${presetTime(info, name).short}`, name, false,
      name === info.default_preset);
    option.dataset.seconds = String(info.preset_times?.[name]?.seconds ?? "");
    select.append(option);
  }
  showPresetTime();
}

// --- start -----------------------------------------------------------------------------------
async function loadInfo() {
  try {
    const info = await api("/v1/info");
    state.info = info;
    fillPresets(info);
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
  $("preset").addEventListener("change", showPresetTime);
  loadInfo();
  const jobId = new URLSearchParams(location.search).get("job");
  if (jobId && /^[0-9a-f-]{36}$/.test(jobId)) follow(jobId);
}

start();
