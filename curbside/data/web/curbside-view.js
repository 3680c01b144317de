// curbside replay viewer. Runs after the page skeleton of curbside/osmseg/webmap.py has created `map`
// (canvas renderer) and `layers` (the layer control), with `VIEW` = {runs, sessions, title} inlined by
// curbside/localize/view.py (curbside/localize/view_data.py writes the runs and sessions). Times are
// seconds on the session clock.

const OFFSET_UNIT_DEG = 1e-6;
const GNSS_COLOUR = VIEW.gnss_colour;  // curbside.osmseg.style.GNSS_FIX_COLOUR
const ui = {
  panel: document.getElementById("panel"),
  panelToggle: document.getElementById("panel-toggle"),
  title: document.getElementById("view-title"),
  clock: document.getElementById("clock"),
  rows: document.querySelector("#run-table tbody"),
  gnssNow: document.getElementById("gnss-now"),
  note: document.getElementById("view-note"),
  summaries: document.getElementById("summaries"),
  play: document.getElementById("play"),
  slider: document.getElementById("slider"),
  speed: document.getElementById("speed"),
  timeLabel: document.getElementById("time-label"),
  nowPlace: document.getElementById("now-place"),
};

function bytesOf(b64) {
  const text = atob(b64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  return bytes;
}

// Little-endian int16 (every browser platform is little-endian; the page writes "<i2").
const int16sOf = (b64) => new Int16Array(bytesOf(b64).buffer);

// Index of the last element of the sorted array `ts` that is <= t; -1 before the first.
function lastAtOrBefore(ts, t) {
  let lo = 0, hi = ts.length - 1, found = -1;
  while (lo <= hi) {
    const mid = (lo + hi) >> 1;
    if (ts[mid] <= t) { found = mid; lo = mid + 1; } else { hi = mid - 1; }
  }
  return found;
}

function interpolate(ts, values, t) {
  if (t <= ts[0]) return values[0];
  if (t >= ts[ts.length - 1]) return values[values.length - 1];
  const k = lastAtOrBefore(ts, t);
  const f = (t - ts[k]) / (ts[k + 1] - ts[k]);
  return values[k] + f * (values[k + 1] - values[k]);
}

function swatch(colour, text) {
  const span = document.createElement("span");
  span.className = "swatch";
  span.style.background = colour;
  span.style.borderColor = colour;
  const label = document.createElement("span");
  label.append(span, " ", text);
  return label.outerHTML;
}

// A canvas over the map, redrawn for the current time by `draw(ctx, map)`.
const TimeCanvas = L.Layer.extend({
  initialize(draw, options) {
    this._draw = draw;
    L.setOptions(this, options);
  },
  onAdd(target) {
    this._canvas = L.DomUtil.create("canvas", "curbside-time-canvas leaflet-zoom-hide");
    this.getPane().appendChild(this._canvas);
    target.on("moveend zoomend resize", this._reset, this);
    this._reset();
  },
  onRemove(target) {
    target.off("moveend zoomend resize", this._reset, this);
    L.DomUtil.remove(this._canvas);
    this._canvas = null;
  },
  redraw() {
    if (!this._canvas) return;
    const ctx = this._canvas.getContext("2d");
    const ratio = window.devicePixelRatio || 1;
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, this._canvas.width, this._canvas.height);
    this._draw(ctx, this._map);
  },
  _reset() {
    const size = this._map.getSize();
    const ratio = window.devicePixelRatio || 1;
    this._canvas.width = size.x * ratio;
    this._canvas.height = size.y * ratio;
    this._canvas.style.width = `${size.x}px`;
    this._canvas.style.height = `${size.y}px`;
    L.DomUtil.setPosition(this._canvas, this._map.containerPointToLayerPoint([0, 0]));
    this.redraw();
  },
});

const state = { index: 0, time: 0, playing: false, clouds: [] };
// Panes: the clouds above the map and tracks, the current positions above the clouds.
map.createPane("clouds").style.zIndex = 450;
map.createPane("now").style.zIndex = 460;
const now = { pane: "now", renderer: L.canvas({ pane: "now" }), interactive: false };

// -- the static and moving layers ------------------------------------------------------------------
const sessionViews = VIEW.sessions.map((s) => {
  const prefix = VIEW.sessions.length > 1 ? `${s.name}: ` : "";
  const view = { data: s };
  if (s.truth) {
    const line = L.polyline(s.truth.lat.map((lat, i) => [lat, s.truth.lon[i]]),
      { color: "#000", weight: 2, dashArray: "6 4", interactive: false });
    const dots = s.truth.lat.map((lat, i) => L.circleMarker([lat, s.truth.lon[i]],
      { radius: 2.5, color: "#000", weight: 1, fillColor: "#fff", fillOpacity: 1, interactive: false }));
    view.truthMarker = L.circleMarker([s.truth.lat[0], s.truth.lon[0]],
      { ...now, radius: 6, color: "#fff", weight: 2, fillColor: "#000", fillOpacity: 1 });
    layers.addOverlay(L.layerGroup([line, ...dots, view.truthMarker]).addTo(map),
      swatch("#000", `${prefix}ground truth (${s.truth.t.length} waypoints)`));
  }
  if (s.gnss) {
    const g = s.gnss;
    const dots = g.lat.map((lat, i) => L.circleMarker([lat, g.lon[i]],
      { radius: 2, stroke: false, fillColor: GNSS_COLOUR, fillOpacity: 0.55, interactive: false }));
    view.circle = L.circle([g.lat[0], g.lon[0]],
      { radius: g.acc[0], color: GNSS_COLOUR, weight: 1.5, fillOpacity: 0.12, interactive: false });
    view.fixMarker = L.circleMarker([g.lat[0], g.lon[0]],
      { ...now, radius: 5, color: "#fff", weight: 1.5, fillColor: GNSS_COLOUR, fillOpacity: 1 });
    layers.addOverlay(L.layerGroup([...dots, view.circle, view.fixMarker]).addTo(map),
      swatch(GNSS_COLOUR, `${prefix}GNSS fixes and accuracy (${g.t.length})`));
  }
  return view;
});
const sessionIndex = new Map(VIEW.sessions.map((s, i) => [s.key, i]));

// The panel's columns that some run has (the others are left out) and the error column's heading.
const COLUMNS = ["segment", "prob", "error", "neff", "recoveries"];
const hasColumn = {
  segment: VIEW.runs.some((r) => r.segment),
  prob: VIEW.runs.some((r) => r.segment_prob),
  error: VIEW.runs.some((r) => r.error_m || r.accuracy_m),
  neff: VIEW.runs.some((r) => r.n_eff),
  recoveries: true,
};
const hasError = VIEW.runs.some((r) => r.error_m), hasRadius = VIEW.runs.some((r) => r.accuracy_m);
for (const th of document.querySelectorAll("#run-table th[data-col]")) th.hidden = !hasColumn[th.dataset.col];
document.querySelector('#run-table th[data-col="error"]').textContent =
  hasError && hasRadius ? "error / 68 % radius" : hasError ? "error" : "68 % radius";

function errorText(r, k, accuracy) {
  const error = r.error_m ? fmt(r.error_m[k], 1, " m") : "\u2014";
  if (!hasRadius) return error;
  return hasError ? `${error} / ${fmt(accuracy, 1, " m")}` : fmt(accuracy, 1, " m");
}

const runViews = VIEW.runs.map((r) => {
  const path = L.polyline(r.lat.map((lat, i) => [lat, r.lon[i]]).filter((p) => p[0] !== null),
    { color: r.colour, weight: 2, opacity: 0.75, interactive: false });
  const marker = L.circleMarker([r.lat[0], r.lon[0]],
    { ...now, radius: 6, color: "#fff", weight: 2, fillColor: r.colour, fillOpacity: 1 });
  // The radius that should hold the walker 68 % of the time (accuracy_m), around the estimate.
  const radius = L.circle([r.lat[0], r.lon[0]], { radius: 0, color: r.colour, weight: 1.5, dashArray: "4 3",
    fillOpacity: 0.06, interactive: false });
  // The legend promises the 68 % radius only for a run that has one.
  layers.addOverlay(L.layerGroup([path, radius, marker]).addTo(map),
    swatch(r.colour, `${r.label}: ${r.accuracy_m ? "track, estimate and its 68 % radius" : "track and estimate"}`));
  const view = { data: r, marker, radius, cloud: null, row: ui.rows.insertRow(),
    session: sessionIndex.get(r.session) };
  view.row.insertCell().innerHTML = swatch(r.colour, r.label);
  view.cells = COLUMNS.map((name) => {
    const cell = view.row.insertCell();
    if (name !== "segment") cell.className = "num";
    cell.hidden = !hasColumn[name];
    return cell;
  });
  if (r.waypoint_summary) {
    const item = document.createElement("li");
    item.textContent = `${r.label}: ${r.waypoint_summary}`;
    ui.summaries.append(item);
  }
  return view;
});

function drawCloud(view) {
  return (ctx, target) => {
    const c = view.cloud;
    if (!c) return;  // not decoded yet
    const k = lastAtOrBefore(c.t, state.time);
    if (k < 0) return;
    ctx.fillStyle = view.data.colour;
    const base = k * c.n;
    const refLat = c.ref_lat[k], refLon = c.ref_lon[k];
    if (!c.alpha) {
      ctx.globalAlpha = 0.55;
      ctx.beginPath();
    }
    for (let i = 0; i < c.n; i++) {
      const p = target.latLngToContainerPoint([refLat + c.dlat[base + i] * OFFSET_UNIT_DEG,
        refLon + c.dlon[base + i] * OFFSET_UNIT_DEG]);
      if (c.alpha) {
        ctx.globalAlpha = 0.1 + 0.8 * c.alpha[base + i] / 255;
        ctx.fillRect(p.x - 1.5, p.y - 1.5, 3, 3);
      } else {
        ctx.rect(p.x - 1.5, p.y - 1.5, 3, 3);
      }
    }
    if (!c.alpha) ctx.fill();
    ctx.globalAlpha = 1;
  };
}

// The cloud layers and their legend entries exist from the start (the legend has its full height when
// the view is fitted); the clouds are decoded after the first render.
for (const view of runViews) {
  const r = view.data;
  if (!r.cloud) continue;
  view.cloudLayer = new TimeCanvas(drawCloud(view), { pane: "clouds" }).addTo(map);
  state.clouds.push(view.cloudLayer);
  const drawn = r.cloud.n < r.cloud.n_total ? `, ${r.cloud.n} drawn` : "";
  layers.addOverlay(view.cloudLayer, swatch(r.colour, `${r.label}: particles (N = ${r.cloud.n_total}${drawn})`));
}

// -- the timeline --------------------------------------------------------------------------------
const timeline = Array.from(new Set(VIEW.runs.flatMap((r) => r.t))).sort((a, b) => a - b);
const t0 = timeline[0];

function fmt(value, digits, unit = "") {
  return value === null || value === undefined ? "\u2014" : `${value.toFixed(digits)}${unit}`;
}

function clockText(t) {
  const s = t - t0;
  const mm = Math.floor(s / 60), ss = (s - 60 * mm).toFixed(1).padStart(4, "0");
  return `t = ${t.toFixed(1)} s (${mm}:${ss} into the walk)`;
}

function updateSession(view, t) {
  const s = view.data;
  if (view.truthMarker) {
    view.truthMarker.setLatLng([interpolate(s.truth.t, s.truth.lat, t), interpolate(s.truth.t, s.truth.lon, t)]);
  }
  if (view.circle) {
    const k = lastAtOrBefore(s.gnss.t, t);
    const j = Math.max(k, 0);
    view.circle.setLatLng([s.gnss.lat[j], s.gnss.lon[j]]).setRadius(s.gnss.acc[j]);
    view.fixMarker.setLatLng([s.gnss.lat[j], s.gnss.lon[j]]);
    view.circle.setStyle({ opacity: k < 0 ? 0 : 1, fillOpacity: k < 0 ? 0 : 0.12 });
    // Runs of several sessions: say whose fix each is.
    const whose = VIEW.sessions.length > 1 ? `${s.name}: ` : "";
    return whose + (k < 0 ? "no GNSS fix yet" :
      `GNSS fix ${(t - s.gnss.t[k]).toFixed(1)} s ago, accuracy ${s.gnss.acc[k].toFixed(0)} m`);
  }
  return "";
}

function updateRun(view, t) {
  const r = view.data;
  const k = lastAtOrBefore(r.t, t);
  const [segment, prob, error, neff, recoveries] = view.cells;
  const accuracy = r.accuracy_m && k >= 0 ? r.accuracy_m[k] : null;
  view.radius.setStyle(accuracy === null || r.lat[k] === null ? { opacity: 0, fillOpacity: 0 }
    : { opacity: 1, fillOpacity: 0.06 });
  if (k < 0 || r.lat[k] === null) {
    view.marker.setStyle({ opacity: 0, fillOpacity: 0 });
    for (const cell of view.cells) cell.textContent = "\u2014";
    segment.title = "";
    return;
  }
  view.marker.setLatLng([r.lat[k], r.lon[k]]).setStyle({ opacity: 1, fillOpacity: 1 });
  if (accuracy !== null) view.radius.setLatLng([r.lat[k], r.lon[k]]).setRadius(accuracy);
  // The segment in words ("Market Street, north side"); its id (the map's segment_id) in the tooltip.
  // An estimate off its segment says so, in the wording of curbside.localize.track_result.place_text.
  const id = r.segment ? r.segment[k] ?? null : null;
  const name = id === null ? null : (r.segment_names?.[id] ?? id);
  const off = r.off_sidewalk_m ? r.off_sidewalk_m[k] ?? null : null;
  segment.textContent = id === null ? "\u2014" : off === null ? name
    : r.off_sidewalk_text.replace("{distance_m}", () => String(off)).replace("{place}", () => name);
  segment.title = id === null ? "" : id;
  prob.textContent = r.segment_prob ? fmt(r.segment_prob[k], 2) : "\u2014";
  error.textContent = errorText(r, k, accuracy);
  neff.textContent = r.n_eff ? fmt(r.n_eff[k], 0) : "\u2014";
  recoveries.textContent = `${r.recoveries_so_far[k]} / ${r.recoveries}`;
  view.row.classList.toggle("recovered", k > 0 && r.recoveries_so_far[k] > r.recoveries_so_far[k - 1]);
}

function setIndex(index) {
  state.index = Math.min(Math.max(index, 0), timeline.length - 1);
  showTime(timeline[state.index]);
  ui.slider.value = String(state.index);
}

function showTime(t) {
  state.time = t;
  const gnss = sessionViews.map((view) => updateSession(view, t)).filter(Boolean);
  ui.gnssNow.textContent = gnss.join("; ");
  for (const view of runViews) updateRun(view, t);
  for (const cloud of state.clouds) cloud.redraw();
  ui.clock.textContent = clockText(t);
  ui.timeLabel.textContent = `${state.index + 1} / ${timeline.length}`;
  speak(t);
}

// -- what a screen reader says -------------------------------------------------------------------
// The slider's value in words (the time, the step, the place) and, in the polite live region, the place
// whenever it changes. Stepping says them at once; while the walk plays both change at most every
// ANNOUNCE_EVERY_MS (one announcement per footstep would chatter). The slider in focus says the place
// itself when stepped (its value text), so the live region then stays quiet. The place is the panel's
// own words for the last run with sidewalk segments (curbside fused, after the baselines, as reported).
const ANNOUNCE_EVERY_MS = 4000;
const placeRun = runViews.findLast((view) => view.data.segment) ?? null;
const spoken = { text: "", at: -Infinity };

function placeNow() {
  if (placeRun === null) return "";
  const words = placeRun.cells[0].textContent;
  return words === "\u2014" ? "no estimate" : words;
}

function speak(t) {
  const wall = performance.now();
  if (state.playing && wall - spoken.at < ANNOUNCE_EVERY_MS) return;
  spoken.at = wall;
  const place = placeNow();
  ui.slider.setAttribute("aria-valuetext",
    `t = ${t.toFixed(1)} s, step ${state.index + 1} of ${timeline.length}${place ? `, ${place}` : ""}`);
  if (place === spoken.text) return;
  spoken.text = place;
  ui.nowPlace.textContent = state.playing || document.activeElement !== ui.slider ? place : "";
}

// -- playback ------------------------------------------------------------------------------------
let lastFrame = null;
function frame(now) {
  if (!state.playing) return;
  if (lastFrame !== null) {
    const t = state.time + (now - lastFrame) / 1000 * Number(ui.speed.value);
    const index = lastAtOrBefore(timeline, t);
    if (index >= timeline.length - 1) {
      setIndex(timeline.length - 1);
      setPlaying(false);
      return;
    }
    state.index = index;
    ui.slider.value = String(index);
    showTime(t);
  }
  lastFrame = now;
  requestAnimationFrame(frame);
}

function setPlaying(playing) {
  if (playing && state.index >= timeline.length - 1) setIndex(0);
  state.playing = playing;
  ui.play.innerHTML = playing ? "&#10074;&#10074;" : "&#9654;";
  ui.play.setAttribute("aria-label", playing ? "pause" : "play");
  lastFrame = null;
  if (playing) requestAnimationFrame(frame);
  else speak(state.time);  // the place where the walk stopped, however soon after the last one
}

ui.title.textContent = VIEW.title;
// What the page cannot show apart (runs of several sessions), said once above the table.
if (VIEW.note) {
  ui.note.textContent = VIEW.note;
  ui.note.hidden = false;
}
document.title = VIEW.title;
ui.slider.max = String(timeline.length - 1);
ui.slider.addEventListener("input", () => { setPlaying(false); setIndex(Number(ui.slider.value)); });
ui.play.addEventListener("click", () => setPlaying(!state.playing));
document.addEventListener("keydown", (event) => {
  if (event.key === " " && event.target.tagName !== "BUTTON" && event.target.tagName !== "SELECT") {
    event.preventDefault();
    setPlaying(!state.playing);
  }
});
setIndex(0);

// -- the panel and the view ------------------------------------------------------------------------
function setPanelOpen(open) {
  ui.panel.classList.toggle("collapsed", !open);
  ui.panelToggle.textContent = open ? "hide" : "show";
  ui.panelToggle.setAttribute("aria-expanded", String(open));
  ui.panelToggle.title = open ? "hide the table (the time stays)" : "show the table";
}
ui.panelToggle.addEventListener("click", () => setPanelOpen(ui.panel.classList.contains("collapsed")));

// An element's box in map-container pixels ({left, top, right, bottom}).
function boxOf(element) {
  const r = element.getBoundingClientRect(), m = map.getContainer().getBoundingClientRect();
  return { left: r.left - m.left, top: r.top - m.top, right: r.right - m.left, bottom: r.bottom - m.top };
}
const overlaps = (a, b) => a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;

// Fit the walk into the part of the map that the panel (with the zoom buttons, top left) and the layer
// control (top right) leave free: beside, below or between them, whichever shows it largest.
function fitView() {
  const bounds = L.latLngBounds(VIEW.bounds);
  const size = map.getSize();
  const corner = (name) => map.getContainer().querySelector(`.leaflet-control-container .leaflet-${name}`);
  const panel = boxOf(ui.panel), zoom = boxOf(corner("top.leaflet-left"));
  const topLeft = { right: Math.max(panel.right, zoom.right), bottom: Math.max(panel.bottom, zoom.bottom) };
  const legend = boxOf(corner("top.leaflet-right"));
  const bottom = Math.max(30, size.y - Math.min(boxOf(corner("bottom.leaflet-left")).top,
    boxOf(corner("bottom.leaflet-right")).top) + 6);
  const m = 16;
  const right = size.x - legend.left + m;
  const candidates = [
    [[topLeft.right + m, m], [right, bottom]],  // between the panel and the legend
    [[m, Math.max(topLeft.bottom, legend.bottom) + m], [m, bottom]],  // below both
    [[topLeft.right + m, legend.bottom + m], [m, bottom]],  // right of the panel, below the legend
    [[m, topLeft.bottom + m], [right, bottom]],  // below the panel, left of the legend
  ];
  let best = null;
  for (const [tl, br] of candidates) {
    const free = L.point(size.x - tl[0] - br[0], size.y - tl[1] - br[1]);
    if (free.x < 80 || free.y < 80) continue;
    const zoom = map.getBoundsZoom(bounds, false, L.point(tl[0] + br[0], tl[1] + br[1]));
    if (best === null || zoom > best.zoom) best = { zoom, tl, br };
  }
  if (best === null) best = { tl: [m, m], br: [m, bottom] };
  map.fitBounds(bounds, { paddingTopLeft: best.tl, paddingBottomRight: best.br, animate: false });
  return best;
}

// On a small screen the panel starts folded: on a phone-wide map (the layer control folded into its
// button), or where it would cover the layer control.
if (layers.options.collapsed || overlaps(boxOf(ui.panel), boxOf(layers.getContainer()))) setPanelOpen(false);
const fitted = fitView();

// First render: the map, tracks and fixes; then the clouds are decoded and the slider enabled.
requestAnimationFrame(() => {
  performance.mark("curbside:first-render");
  for (const view of runViews) {
    const r = view.data;
    if (!r.cloud) continue;
    view.cloud = {
      t: r.cloud.t, n: r.cloud.n, ref_lat: r.cloud.ref_lat, ref_lon: r.cloud.ref_lon,
      dlat: int16sOf(r.cloud.dlat), dlon: int16sOf(r.cloud.dlon),
      alpha: r.cloud.alpha ? bytesOf(r.cloud.alpha) : null,
    };
  }
  setIndex(0);
  ui.slider.disabled = false;
  ui.play.disabled = false;
  performance.mark("curbside:slider-ready");
});
window.curbsideView = { timeline, state, setIndex, runs: runViews, fitted, fitView, setPanelOpen };
