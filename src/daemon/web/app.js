// The easyhec daemon's page: one button, live progress from the SSE stream, overlays as
// views arrive, the active result with its uncertainty, bump checks and history.
//
// The token comes from `?token=` (then removed from the address bar) or the login form and
// is kept in sessionStorage for this tab only. Every API call sends it as a bearer token;
// EventSource cannot send headers, so the SSE stream is read with fetch().
"use strict";

const TOKEN_KEY = "easyhec-token";
const $ = (id) => document.getElementById(id);
let following = null; // id whose event stream is open
let shownId = null; // calibration whose views are in the overlay strip
const overlayViews = new Map(); // view index -> <img>
let pinned = null; // a past calibration the user picked in the history, shown until cleared
// The export formats' names, read once from /openapi.json (the daemon's one list of them).
let exportFormats = null;
const rounds = []; // per-round points of the calibration in the chart
let chartId = null;
// The cell's camera names when its config lists [[camera]] tables (each camera then has its
// own active calibration and overlays); null for a single [camera].
let cameraNames = null;

function token() {
  return sessionStorage.getItem(TOKEN_KEY);
}

function takeTokenFromUrl() {
  const url = new URL(window.location.href);
  const t = url.searchParams.get("token");
  if (t) {
    sessionStorage.setItem(TOKEN_KEY, t);
    url.searchParams.delete("token");
    window.history.replaceState(null, "", url.pathname + url.search + url.hash);
  }
}

function showLogin(message) {
  $("app").hidden = true;
  $("login").hidden = false;
  $("login-message").textContent = message || "";
}

class Unauthorized extends Error {}

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {}, {
    Authorization: "Bearer " + (token() || ""),
  });
  const resp = await fetch(path, Object.assign({}, options, { headers }));
  if (resp.status === 401) {
    sessionStorage.removeItem(TOKEN_KEY);
    showLogin("The daemon refused that token.");
    throw new Unauthorized("unauthorized");
  }
  return resp;
}

async function json(path, options) {
  const resp = await api(path, options);
  let body = null;
  try {
    body = await resp.json();
  } catch (_) {
    body = null;
  }
  return { status: resp.status, body };
}

function fmt(v, digits) {
  return v === null || v === undefined ? "—" : Number(v).toFixed(digits);
}

function setState(el, state) {
  el.textContent = state;
  el.className = "state " + state;
}

function showStatus(s) {
  $("cal-id").textContent = s.id + (s.trigger === "bump" ? " (after a bump)" : "") + (s.dry_run ? " (dry run)" : "");
  setState($("state"), s.state);
  $("phase").textContent = s.phase ? s.phase : "";
  $("views").textContent = s.views;
  $("max").textContent = s.max_views;
  $("round").textContent = s.round === null || s.round === undefined ? "—" : s.round;
  $("loss").textContent = fmt(s.loss, 5);
  $("iou").textContent = fmt(s.mean_iou, 4);
  $("variance").textContent = s.best_variance === null || s.best_variance === undefined ? "—" : fmt(s.best_variance, 1) + " px";
  let reason = s.stop_reason || "—";
  if (s.error) reason = s.error;
  if (s.planned_poses !== null && s.planned_poses !== undefined) reason += " (" + s.planned_poses + " poses planned)";
  if (s.truth_error) {
    reason += " — vs simulated truth " + fmt(s.truth_error.rotation_deg, 3) + "° / " + fmt(s.truth_error.translation_mm, 2) + " mm";
  }
  $("stop-reason").textContent = reason;
  const p = $("progress");
  p.max = Math.max(1, s.max_views);
  p.value = s.views;
  const running = s.state === "running" || s.state === "queued";
  $("start").disabled = running;
  $("cancel").hidden = !running;
  $("cancel").dataset.id = s.id;
}

function resetOverlays(id) {
  shownId = id;
  overlayViews.clear();
  $("overlays").replaceChildren();
}

async function loadOverlay(id, n, camera) {
  let url = "/api/v1/calibrations/" + encodeURIComponent(id) + "/views/" + n + "/overlay.png";
  if (camera === null) {
    await loadImage(id, n, "view " + n, url);
    return;
  }
  url += "?camera=" + encodeURIComponent(camera);
  await loadImage(id, camera + "/" + n, camera + " · view " + n, url);
}

// A dry run's planned pose `k`, drawn over the first view (of `camera` in a list).
async function loadPlanned(id, k, camera) {
  const url = "/api/v1/calibrations/" + encodeURIComponent(id) + "/plan/" + k + "/overlay.png";
  if (camera === null) {
    await loadImage(id, "plan-" + k, "planned pose " + (k + 1), url);
    return;
  }
  const query = "?camera=" + encodeURIComponent(camera);
  await loadImage(id, camera + "/plan-" + k, camera + " · planned pose " + (k + 1), url + query);
}

async function loadImage(id, key, caption, url) {
  // A strip that was switched to another calibration while this one loaded gets nothing.
  if (shownId !== id) return;
  let img = overlayViews.get(key);
  if (!img) {
    const fig = document.createElement("figure");
    img = document.createElement("img");
    img.alt = caption;
    img.dataset.key = String(key);
    const cap = document.createElement("figcaption");
    cap.textContent = caption;
    fig.append(img, cap);
    $("overlays").append(fig);
    overlayViews.set(key, img);
  }
  const resp = await api(url);
  if (!resp.ok || shownId !== id) return;
  const blob = await resp.blob();
  if (shownId !== id) return;
  const old = img.src;
  img.src = URL.createObjectURL(blob);
  img.dataset.loaded = "1";
  if (old && old.startsWith("blob:")) URL.revokeObjectURL(old);
}

async function showOverlays(s, reloadAll) {
  if (shownId !== s.id) resetOverlays(s.id);
  if (!s.camera_from_base) return;
  // The cameras this run calibrated (a recalibration after a bump takes only the stale ones).
  const cameras = (cameraNames && s.cameras) || cameraNames || [null];
  for (let n = 0; n < s.views; n++) {
    for (const camera of cameras) {
      const key = camera === null ? n : camera + "/" + n;
      if (reloadAll || !overlayViews.has(key)) await loadOverlay(s.id, n, camera);
    }
  }
  const planned = s.dry_run && s.planned_poses ? s.planned_poses : 0;
  for (let k = 0; k < planned; k++) {
    for (const camera of cameras) {
      const key = camera === null ? "plan-" + k : camera + "/plan-" + k;
      if (reloadAll || !overlayViews.has(key)) await loadPlanned(s.id, k, camera);
    }
  }
}

// The export formats the download route takes: the enum of its `format` parameter in the
// daemon's own API description, so the page never keeps a list of its own.
// Tried again on each refresh until it succeeds.
async function loadExportFormats() {
  if (exportFormats) return;
  try {
    const resp = await fetch("/openapi.json");
    if (!resp.ok) return;
    const doc = await resp.json();
    const route = doc.paths["/api/v1/calibrations/{id}/export/{format}"];
    const param = route && route.get.parameters.find((p) => p.name === "format");
    const schema = param ? param.schema : {};
    const names = schema.enum || (schema.oneOf || []).flatMap((o) => o.enum || []);
    if (names.length > 0) exportFormats = names;
  } catch (e) {
    $("message").textContent = "cannot read the export formats from /openapi.json: " + e;
  }
}

// The result's forms as download buttons, once the calibration has a result.
function showDownloads(s) {
  const box = $("downloads");
  const ready = Boolean(s.camera_from_base) && !s.dry_run && !["running", "queued"].includes(s.state);
  const formats = String((exportFormats || []).length);
  if (box.dataset.id === s.id && box.dataset.ready === String(ready) && box.dataset.formats === formats) return;
  box.dataset.id = s.id;
  box.dataset.ready = String(ready);
  box.dataset.formats = formats;
  if (!ready) {
    const note = document.createElement("span");
    note.className = "muted";
    note.textContent = "Exports appear when a run has a result.";
    box.replaceChildren(note);
    return;
  }
  // One row of buttons per camera the run calibrated in a list, each file named by its camera.
  const cameras = (cameraNames && s.cameras) || cameraNames || [null];
  box.replaceChildren(
    ...cameras.map((camera) => {
      const row = document.createElement("div");
      if (camera !== null) row.append(camera + ": ");
      row.dataset.camera = camera === null ? "" : camera;
      for (const format of exportFormats || []) {
        const b = document.createElement("button");
        b.textContent = format;
        b.dataset.format = format;
        b.onclick = () => download(s.id, format, b, camera);
        row.append(b);
      }
      return row;
    }),
  );
}

// Fetches an export (of `camera` in a list) with the token (a plain link cannot send it) and
// saves it under the name the daemon gives.
async function download(id, format, button, camera) {
  const query = camera === null ? "" : "?camera=" + encodeURIComponent(camera);
  const resp = await api("/api/v1/calibrations/" + encodeURIComponent(id) + "/export/" + format + query);
  button.dataset.status = String(resp.status);
  if (!resp.ok) {
    const body = await resp.json().catch(() => null);
    $("message").textContent = (body && body.error) || "HTTP " + resp.status;
    return;
  }
  const blob = await resp.blob();
  const named = (resp.headers.get("Content-Disposition") || "").match(/filename="([^"]+)"/);
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = named ? named[1] : id + "." + format;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  button.dataset.bytes = String(blob.size);
}

// One point per solved round: loss, best variance and the 1-sigma translation's norm.
function recordRound(s) {
  if (chartId !== s.id) {
    chartId = s.id;
    rounds.length = 0;
  }
  if (s.round === null || s.round === undefined) return drawChart();
  const u = s.uncertainty ? Math.hypot(...s.uncertainty.translation_mm) : null;
  const point = { round: s.round, loss: s.loss, variance: s.best_variance, unc: u };
  const i = rounds.findIndex((p) => p.round === s.round);
  if (i >= 0) rounds[i] = point;
  else rounds.push(point);
  drawChart();
}

function drawChart() {
  const c = $("chart");
  const g = c.getContext("2d");
  const [w, h, pad] = [c.width, c.height, 12];
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#d0d5dd";
  g.strokeRect(pad, pad, w - 2 * pad, h - 2 * pad);
  c.dataset.points = String(rounds.length);
  const x = (i) => pad + (rounds.length > 1 ? (i * (w - 2 * pad)) / (rounds.length - 1) : (w - 2 * pad) / 2);
  for (const [key, colour] of [["loss", "#2454c5"], ["variance", "#b42318"], ["unc", "#1a7f37"]]) {
    const values = rounds.map((p) => p[key]);
    const finite = values.filter((v) => v !== null && v !== undefined && Number.isFinite(v));
    if (!finite.length) continue;
    const top = Math.max(...finite) || 1;
    g.strokeStyle = g.fillStyle = colour;
    g.beginPath();
    let started = false;
    values.forEach((v, i) => {
      if (v === null || v === undefined || !Number.isFinite(v)) return;
      const y = h - pad - (v / top) * (h - 2 * pad);
      if (started) g.lineTo(x(i), y);
      else g.moveTo(x(i), y);
      started = true;
      g.fillRect(x(i) - 2, y - 2, 4, 4);
    });
    g.stroke();
  }
}

// A past calibration picked in the history: its status, overlays and exports stay shown
// until another is picked or a run starts.
function showPast(c) {
  if (following) {
    $("message").textContent = "A calibration is running: pick a past one when it has ended.";
    return;
  }
  pinned = c.id;
  showStatus(c);
  if (chartId !== c.id) recordRound(c);
  showDownloads(c);
  showOverlays(c, true);
}

function handleEvent(e) {
  const s = e.status;
  showStatus(s);
  showDownloads(s);
  if (e.kind === "round" || e.kind === "state") recordRound(s);
  if (e.kind === "round") showOverlays(s, false);
  if (e.kind === "state" && s.state !== "running" && s.state !== "queued") {
    showOverlays(s, true);
  }
}

async function follow(id) {
  if (following === id) return;
  following = id;
  resetOverlays(id);
  try {
    const resp = await api("/api/v1/calibrations/" + encodeURIComponent(id) + "/events");
    if (!resp.ok || !resp.body) throw new Error("event stream: HTTP " + resp.status);
    const reader = resp.body.getReader();
    const decoder = new TextDecoder();
    let buffer = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += decoder.decode(value, { stream: true }).replace(/\r/g, "");
      let end;
      while ((end = buffer.indexOf("\n\n")) >= 0) {
        const block = buffer.slice(0, end);
        buffer = buffer.slice(end + 2);
        const data = block
          .split("\n")
          .filter((l) => l.startsWith("data:"))
          .map((l) => l.slice(5).trim())
          .join("\n");
        if (data) handleEvent(JSON.parse(data));
      }
    }
  } catch (err) {
    if (!(err instanceof Unauthorized)) $("message").textContent = String(err);
  } finally {
    following = null;
  }
  await refresh();
}

function showActive(a) {
  if (!a) {
    $("no-result").hidden = false;
    $("result-body").hidden = true;
    return;
  }
  $("no-result").hidden = true;
  $("result-body").hidden = false;
  $("result-id").textContent = a.id;
  $("result").dataset.id = a.id;
  const stale = $("stale");
  stale.textContent = a.stale ? "stale: camera moved" : "fits";
  stale.className = "badge " + (a.stale ? "bad" : "ok");
  $("activated-at").textContent = "active since " + a.activated_at;
  const r = a.result;
  $("matrix").textContent = r.camera_from_base
    .map((row) => row.map((v) => (v >= 0 ? " " : "") + v.toFixed(5)).join("  "))
    .join("\n");
  if (r.uncertainty) {
    $("unc-rot").textContent = r.uncertainty.rotation_deg.map((v) => v.toFixed(4)).join(", ") + " °";
    $("unc-trans").textContent = r.uncertainty.translation_mm.map((v) => v.toFixed(3)).join(", ") + " mm";
    const bound = r.uncertainty.camera_centre_95_mm;
    $("unc-centre").textContent = bound == null ? "—" : "within " + bound.toFixed(2) + " mm";
    $("unc-dominant").textContent = termsText(r.uncertainty.terms);
  }
  $("views-used").textContent = r.views_used.join(", ");
  $("result-reason").textContent = r.stop_reason;
}

// Which term sets the uncertainty, with each term's own 95% centre bound.
function termsText(t) {
  if (!t) return "—";
  const parts = ["statistical " + t.statistical_centre_95_mm.toFixed(2) + " mm"];
  if (t.inter_view_centre_95_mm != null) {
    parts.push("inter-view " + t.inter_view_centre_95_mm.toFixed(2) + " mm");
  }
  if (t.mask_bias_centre_95_mm != null) {
    parts.push("mask bias " + t.mask_bias_centre_95_mm.toFixed(2) + " mm");
  }
  if (t.segmentation_centre_95_mm != null) {
    parts.push("segmentation " + t.segmentation_centre_95_mm.toFixed(2) + " mm");
  }
  if (t.segmentation_not_measured != null) {
    parts.push("segmentation not measured: " + t.segmentation_not_measured);
  }
  return t.dominant + " (" + parts.join(", ") + ")";
}

// A cell of several cameras: one row per camera with its active calibration and last check.
function showCameras(list) {
  $("no-result").hidden = true;
  $("result-body").hidden = true;
  $("cameras-body").hidden = false;
  const rows = list.map((c) => {
    const tr = document.createElement("tr");
    tr.dataset.camera = c.camera;
    const a = c.active;
    const u = a && a.result.uncertainty;
    const check = a && a.last_check;
    const cells = [
      c.camera,
      a ? a.id : "none yet",
      a ? (a.stale ? "stale: camera moved" : "fits") : "—",
      u && u.camera_centre_95_mm != null ? "within " + u.camera_centre_95_mm.toFixed(2) + " mm" : "—",
      check ? check.at + ": " + (check.stale ? "moved" : "not moved") + ", IoU " + fmt(check.iou, 4) : "—",
    ];
    for (const [i, text] of cells.entries()) {
      const td = document.createElement("td");
      td.textContent = text;
      if (i === 2 && a) td.className = "badge " + (a.stale ? "bad" : "ok");
      tr.append(td);
    }
    return tr;
  });
  $("cameras").replaceChildren(...rows);
}

// What a check took out as its segmenter's fat or thin habit before measuring, if anything.
function offsetNote(c) {
  const px = c.mask_offset_px || 0;
  return Math.abs(px) >= 0.005 ? ", masks " + fmt(Math.abs(px), 2) + " px " + (px > 0 ? "fat" : "thin") + " (taken out)" : "";
}

// The verdict of a check of several cameras: which moved, if any.
function showChecks(list) {
  if (!list || !list.length) return;
  const moved = list.filter((c) => c.stale).map((c) => c.camera);
  const v = $("check-verdict");
  v.textContent = moved.length ? "bump detected: " + moved.join(", ") + " stale" : "no camera has moved";
  v.className = "badge " + (moved.length ? "bad" : "ok");
  $("check-at").textContent = list[0].at + " (" + list[0].trigger + ")";
  $("check-iou").textContent = list.map((c) => c.camera + " " + fmt(c.iou, 4)).join(", ");
  $("check-boundary").textContent = list.map((c) => c.camera + " " + fmt(c.boundary_px, 2) + " px" + offsetNote(c)).join(", ");
  $("check-recal").textContent = list[0].recalibration || "—";
}

function showCheck(c) {
  if (!c) return;
  const v = $("check-verdict");
  v.textContent = c.stale ? "bump detected: calibration stale" : "camera has not moved";
  v.className = "badge " + (c.stale ? "bad" : "ok");
  $("check-at").textContent = c.at + " (" + c.trigger + ", " + c.calibration_id + ")";
  $("check-iou").textContent = fmt(c.iou, 4) + " (stale below " + c.min_iou + ")";
  $("check-boundary").textContent = fmt(c.boundary_px, 2) + " px (stale above " + c.max_boundary_px + " px)" + offsetNote(c);
  $("check-recal").textContent = c.recalibration || "—";
}

function showHistory(list, activeId) {
  const rows = list.map((c) => {
    const tr = document.createElement("tr");
    const cells = [
      null,
      c.state,
      String(c.views),
      c.started_at || c.created_at,
      c.error || c.stop_reason || "",
    ];
    for (const [i, text] of cells.entries()) {
      const td = document.createElement("td");
      if (i === 0) {
        const show = document.createElement("button");
        show.className = "link";
        show.dataset.id = c.id;
        show.textContent = c.id + (c.id === activeId ? " ★" : "");
        show.onclick = () => showPast(c);
        td.append(show);
        tr.append(td);
        continue;
      }
      td.textContent = text;
      if (i === 1) td.className = "state " + c.state;
      tr.append(td);
    }
    const td = document.createElement("td");
    // The daemon activates only a succeeded run, or an interrupted one re-solved offline
    // (its refusal says why otherwise).
    const activatable = ["succeeded", "interrupted"].includes(c.state);
    if (activatable && c.id !== activeId && !c.dry_run) {
      const b = document.createElement("button");
      b.textContent = "Activate";
      b.onclick = async () => {
        const { status, body } = await json("/api/v1/calibrations/" + encodeURIComponent(c.id) + "/activate", { method: "POST" });
        $("message").textContent = status === 200 ? "" : body && body.error;
        refresh();
      };
      td.append(b);
    }
    tr.append(td);
    return tr;
  });
  $("history").replaceChildren(...rows);
}

async function refresh() {
  await loadExportFormats();
  try {
    const [hist, active, checks, cams] = await Promise.all([
      json("/api/v1/calibrations"),
      json("/api/v1/calibration"),
      json("/api/v1/checks"),
      json("/api/v1/cameras"),
    ]);
    const list = (hist.body && hist.body.calibrations) || [];
    const listed = Boolean(cams.body && cams.body.listed);
    cameraNames = listed ? cams.body.cameras.map((c) => c.camera) : null;
    showHistory(list, hist.body && hist.body.active);
    const recent = (checks.body && checks.body.checks) || [];
    if (listed) {
      showCameras(cams.body.cameras);
      // The newest check's records: one per camera, all taken at the same time.
      showChecks(recent.filter((c) => recent.length && c.at === recent[0].at));
    } else {
      showActive(active.status === 200 ? active.body : null);
      showCheck(recent[0]);
    }
    const live = list.find((c) => c.state === "running" || c.state === "queued");
    const picked = pinned && list.find((c) => c.id === pinned);
    if (live) {
      pinned = null;
      follow(live.id);
    } else if (picked && !following) {
      showStatus(picked);
      showDownloads(picked);
    } else if (list.length && !following) {
      showStatus(list[0]);
      showDownloads(list[0]);
      if (shownId !== list[0].id) showOverlays(list[0], true);
    }
  } catch (err) {
    if (!(err instanceof Unauthorized)) $("message").textContent = String(err);
  }
}

async function start() {
  $("message").textContent = "";
  pinned = null;
  const mv = parseInt($("max-views").value, 10);
  const body = Number.isFinite(mv) ? { max_views: mv } : {};
  if ($("dry-run").checked) body.dry_run = true;
  const { status, body: reply } = await json("/api/v1/calibrations", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body),
  });
  if (status === 202) {
    follow(reply.id);
  } else {
    $("message").textContent = (reply && reply.error) || "HTTP " + status;
  }
}

// The cell's camera names for a list of cameras, [null] for one [camera] table; asked of
// the daemon, so a click before the page's first refresh still names every camera.
async function cellCameras() {
  const { status, body } = await json("/api/v1/cameras");
  if (status === 200 && body && body.listed) return body.cameras.map((c) => c.camera);
  return [null];
}

// One live frame from each camera, to frame them before a run.
async function preview() {
  $("message").textContent = "";
  const figures = [];
  for (const camera of await cellCameras()) {
    let url = "/api/v1/camera/preview.png";
    if (camera !== null) url += "?camera=" + encodeURIComponent(camera);
    const resp = await api(url);
    if (!resp.ok) {
      const body = await resp.json().catch(() => null);
      const why = (body && body.error) || "HTTP " + resp.status;
      $("message").textContent = camera === null ? why : camera + ": " + why;
      for (const fig of figures) URL.revokeObjectURL(fig.querySelector("img").src);
      return;
    }
    figures.push(previewFigure(camera, await resp.blob()));
  }
  const box = $("previews");
  for (const img of box.querySelectorAll("img")) URL.revokeObjectURL(img.src);
  box.replaceChildren(...figures);
}

// A preview frame, captioned with its camera's name in a list.
function previewFigure(camera, blob) {
  const fig = document.createElement("figure");
  const img = document.createElement("img");
  img.src = URL.createObjectURL(blob);
  if (camera === null) {
    img.id = "preview";
    img.alt = "camera preview";
    fig.append(img);
    return fig;
  }
  img.dataset.camera = camera;
  img.alt = camera + " preview";
  const cap = document.createElement("figcaption");
  cap.textContent = camera;
  fig.append(img, cap);
  return fig;
}

async function cancel() {
  const id = $("cancel").dataset.id;
  const { status, body } = await json("/api/v1/calibrations/" + encodeURIComponent(id) + "/cancel", { method: "POST" });
  if (status !== 202) $("message").textContent = (body && body.error) || "HTTP " + status;
}

async function check() {
  $("check").disabled = true;
  $("message").textContent = "";
  try {
    const { status, body } = await json("/api/v1/checks", { method: "POST" });
    if (status === 200 && body.checks) showChecks(body.checks);
    else if (status === 200) showCheck(body);
    else $("message").textContent = (body && body.error) || "HTTP " + status;
  } finally {
    $("check").disabled = false;
  }
  refresh();
}

function boot() {
  takeTokenFromUrl();
  $("login-form").onsubmit = (e) => {
    e.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $("token-input").value.trim());
    boot();
  };
  if (!token()) {
    showLogin("");
    return;
  }
  $("login").hidden = true;
  $("app").hidden = false;
  $("start").onclick = start;
  $("cancel").onclick = cancel;
  $("check").onclick = check;
  $("preview-button").onclick = preview;
  refresh();
}

boot();
setInterval(() => {
  if (token() && !following) refresh();
}, 5000);
