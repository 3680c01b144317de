// curbside map editor, vertex mode: the selected polygon reshaped by keyboard, one vertex at a time.
// curbside/osmseg/edit.py puts it just before curbside-edit.js in one script: it only defines; its
// functions use that file's `editor`, `ui`, `say`, `setOutline`, `commitGeometry`..., which sets it up.
// Its edits take the pointer's path: commitGeometry's self-intersection check, the 3-vertex rule, the
// undo stack, "geometry" in the saved file.

const STEP_M = { fine: 0.1, normal: 1, large: 10 };  // an arrow key's move: with Shift, plain, with Ctrl
// [east, north] unit moves
const ARROWS = { ArrowUp: [0, 1], ArrowDown: [0, -1], ArrowLeft: [-1, 0], ArrowRight: [1, 0] };
const WGS84_A_M = 6378137;
const WGS84_E2 = 0.00669437999014;
const vertexMode = { layer: null, index: 0, from: null, marker: null };

// A polygon's rings (the outer ring and holes, of each part of a multipolygon), in order.
function ringsOf(latlngs) {
  return latlngs.length && !Array.isArray(latlngs[0]) ? [latlngs] : latlngs.flatMap(ringsOf);
}

// The k-th vertex counted over all rings: its ring, the ring's number and the vertex's index there.
function vertexAt(rings, k) {
  let r = 0;
  for (; k >= rings[r].length; r += 1) k -= rings[r].length;
  return { ring: rings[r], r, i: k };
}

// Metres per degree of latitude and of longitude on the WGS84 ellipsoid at a latitude: the meridian and
// prime-vertical radii of curvature there (a 10 m step lands within 0.01 mm of the geodesic's 10 m).
function metresPerDegree(lat) {
  const phi = (lat * Math.PI) / 180;
  const w = 1 - WGS84_E2 * Math.sin(phi) ** 2;
  const radian = Math.PI / 180;
  return {
    north: ((WGS84_A_M * (1 - WGS84_E2)) / w ** 1.5) * radian,
    east: (WGS84_A_M / Math.sqrt(w)) * Math.cos(phi) * radian,
  };
}

function metres(value, positive, negative) {
  return `${Number(Math.abs(value).toFixed(2))} m ${value < 0 ? negative : positive}`;
}

function vertexText() {
  const { layer, index } = vertexMode;
  const rings = ringsOf(layer.getLatLngs());
  const { ring, r, i } = vertexAt(rings, index);
  const ringText = rings.length > 1 ? ` of ring ${r + 1} of ${rings.length}` : "";
  return `vertex ${i + 1} of ${ring.length}${ringText} of polygon ${layer.curbside.id}, at `
    + `lat ${ring[i].lat.toFixed(EDIT.decimals)}, lon ${ring[i].lng.toFixed(EDIT.decimals)}`;
}

// The highlight on the current vertex (kept in range after an edit), in view; returns its position.
function showVertex() {
  const rings = ringsOf(vertexMode.layer.getLatLngs());
  const count = rings.reduce((n, ring) => n + ring.length, 0);
  vertexMode.index = Math.min(vertexMode.index, count - 1);
  const { ring, i } = vertexAt(rings, vertexMode.index);
  vertexMode.marker.setLatLng(ring[i]);
  vertexMode.marker.getElement().firstChild.textContent = String(i + 1);
  map.panInside(ring[i], { padding: [60, 60], animate: false });
  return L.latLng(ring[i].lat, ring[i].lng);
}

function setVertexModeUi(on) {
  const area = map.getContainer();
  // A screen reader passes the keys through to an application, not to a region it reads.
  area.setAttribute("role", on ? "application" : "region");
  area.setAttribute("aria-label", on ? `map, vertex mode on polygon ${vertexMode.layer.curbside.id}` : "map");
  area.setAttribute("aria-describedby", on ? "vertex-help" : "map-help");
  ui.vertexButton.setAttribute("aria-pressed", String(on));
}

// Vertex mode on the selected polygon, from its index-th vertex; `resumed` (after an undo): the focus stays.
function enterVertexMode(index = 0, resumed = false) {
  const layer = editor.selected;
  if (!layer) {
    say("select a polygon first (in the list of polygons), then V moves its vertices", true);
    return false;
  }
  vertexMode.layer = layer;
  vertexMode.index = index;
  vertexMode.marker ??= L.marker(layer.getCenter(), {
    icon: L.divIcon({ className: "current-vertex", html: "<span></span>", iconSize: [26, 26] }),
    interactive: false, keyboard: false, pane: "currentVertex", pmIgnore: true,
  });
  vertexMode.marker.addTo(map);
  vertexMode.marker.getElement().setAttribute("aria-hidden", "true");
  vertexMode.from = showVertex();
  setVertexModeUi(true);
  if (resumed) return true;
  map.getContainer().focus();
  say(`vertex mode: N and P step through the vertices, the arrow keys move it ${STEP_M.normal} m `
    + `(Shift ${STEP_M.fine} m, Ctrl ${STEP_M.large} m), I inserts a vertex, Delete removes it, Esc leaves. `
    + vertexText());
  ui.message.scrollIntoView({ block: "nearest" });  // the panel, not the focus: its messages in sight
  return true;
}

function leaveVertexMode(quiet = false) {
  const layer = vertexMode.layer;
  if (!layer) return;
  vertexMode.layer = null;
  vertexMode.marker.remove();
  setVertexModeUi(false);
  if (!quiet) say(`vertex mode off; polygon ${layer.curbside.id} stays selected`);
}

function stepVertex(by) {
  const count = ringsOf(vertexMode.layer.getLatLngs()).reduce((n, ring) => n + ring.length, 0);
  vertexMode.index = (vertexMode.index + by + count) % count;
  vertexMode.from = showVertex();
  say(vertexText());
}

// Change the outline through `change(rings)` (on a copy; it returns a reason to refuse, or nothing),
// then commit it as a pointer's edit would be. Returns whether it went through.
function reshape(what, change, refusal) {
  const layer = vertexMode.layer;
  const latlngs = cloneLatLngs(layer.getLatLngs());
  const refused = change(ringsOf(latlngs));
  if (refused) {
    say(`polygon ${layer.curbside.id}: ${refused}`, true);
    return false;
  }
  setOutline(layer, latlngs);
  return commitGeometry(layer, what, refusal);
}

function moveVertex(east_m, north_m) {
  const k = vertexMode.index;
  const moved = reshape("vertex move", (rings) => {
    const { ring, i } = vertexAt(rings, k);
    const scale = metresPerDegree(ring[i].lat);
    ring[i] = L.latLng(ring[i].lat + north_m / scale.north, ring[i].lng + east_m / scale.east);
  }, `moving vertex ${k + 1} there would make its outline cross itself; it stays where it was`);
  if (!moved) return;
  const { from } = vertexMode;
  const at = vertexAt(ringsOf(vertexMode.layer.getLatLngs()), k);
  const scale = metresPerDegree(from.lat);
  const step = east_m ? metres(east_m, "east", "west") : metres(north_m, "north", "south");
  const east = metres((at.ring[at.i].lng - from.lng) * scale.east, "east", "west");
  const north = metres((at.ring[at.i].lat - from.lat) * scale.north, "north", "south");
  say(`moved ${step}: ${east}, ${north} of where it was; ${vertexText()}`);
}

function insertVertex() {
  const k = vertexMode.index;
  const inserted = reshape("vertex insertion", (rings) => {
    const { ring, i } = vertexAt(rings, k);
    const [a, b] = [ring[i], ring[(i + 1) % ring.length]];
    ring.splice(i + 1, 0, L.latLng((a.lat + b.lat) / 2, (a.lng + b.lng) / 2));
  }, "that vertex would make its outline cross itself");
  if (!inserted) return;
  vertexMode.index = k + 1;
  vertexMode.from = showVertex();
  say(`vertex added midway to the next one: ${vertexText()}`);
}

function removeVertex() {
  const k = vertexMode.index;
  const removed = reshape("vertex removal", (rings) => {
    const { ring, i } = vertexAt(rings, k);
    if (ring.length <= 3) return TOO_FEW_VERTICES;
    ring.splice(i, 1);
    return null;
  }, `removing vertex ${k + 1} would make its outline cross itself; it is back`);
  if (!removed) return;
  vertexMode.from = showVertex();
  say(`vertex removed; now ${vertexText()}`);
}

const VERTEX_KEYS = {
  n: () => stepVertex(1), p: () => stepVertex(-1), i: insertVertex, Insert: insertVertex,
  Delete: removeVertex, Backspace: removeVertex, Escape: () => leaveVertexMode(), v: () => leaveVertexMode(),
};

// In vertex mode, with the map focused, these keys are its own: before Leaflet's (which pans on arrows).
function onVertexKey(event) {
  if (!vertexMode.layer || document.activeElement !== map.getContainer() || event.altKey) return;
  const large = event.ctrlKey || event.metaKey;
  const key = event.key.length === 1 ? event.key.toLowerCase() : event.key;
  let act = large ? null : VERTEX_KEYS[key];
  if (ARROWS[key]) {
    const step = large ? STEP_M.large : event.shiftKey ? STEP_M.fine : STEP_M.normal;
    act = () => moveVertex(ARROWS[key][0] * step, ARROWS[key][1] * step);
  }
  if (!act) return;  // Ctrl+Z and the others go on to onKey
  event.preventDefault();
  event.stopPropagation();
  act();
}
