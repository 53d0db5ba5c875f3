// Requests to the service with the API key; its JSON errors become Error objects.
import { $, state } from "./page.js";

export function apiKey() { return $("api-key").value.trim(); }

export function authHeaders() {
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

export async function api(path, options = {}) {
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

export function upload(path, form, onProgress) {
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

export async function artifactUrl(url) {
  if (!apiKey()) return url;  // plain URLs stream (and seek) directly
  const response = await fetch(url, { headers: authHeaders() });
  const objectUrl = URL.createObjectURL(await response.blob());
  state.objectUrls.push(objectUrl);
  return objectUrl;
}
