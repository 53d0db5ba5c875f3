// CAD-NeRF web page: pick and order photos, submit, follow progress, show the result.
import { $, state, showError } from "./page.js";
import { api, apiKey } from "./api.js";
import { renderCount, setUpDropZone, submitJob } from "./upload.js";
import { follow, cancelJob } from "./job.js";

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
