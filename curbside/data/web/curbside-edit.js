// curbside map editor. Runs after the page skeleton of curbside/osmseg/webmap.py has created `map` and
// `layers`, with Leaflet-Geoman loaded and `EDIT` = {source, filename, generator, meta, classes,
// decimals, window, features, kept_count} inlined by curbside/osmseg/edit.py; the features outside the
// window, saved unchanged, wait as JSON in the element #edit-kept (KEPT_ELEMENT_ID there). Vertex mode
// (reshaping by keyboard) is defined in curbside-edit-vertex.js, which comes just before this file.

const CLASSES = Object.keys(EDIT.classes);
const SIDEWALK_FIELDS = ["segment_id", "street", "side"];
const EDIT_KINDS = ["geometry", "class", "fields", "drawn"];
const SELECTED_STYLE = { color: "#00a5c8", weight: 3, opacity: 1 };
const UNDO_STEPS = 500;  // edits kept for undo (each holds one polygon's state)
const ui = {
  source: document.getElementById("edit-source"),
  list: document.getElementById("feature-list"),
  drawClass: document.getElementById("draw-class"),
  selection: document.getElementById("selection"),
  selectionTitle: document.getElementById("selection-title"),
  selectionState: document.getElementById("selection-state"),
  featureClass: document.getElementById("feature-class"),
  sidewalkFields: document.getElementById("sidewalk-fields"),
  fields: Object.fromEntries(SIDEWALK_FIELDS.map((f) => [f, document.getElementById(`field-${f}`)])),
  remove: document.getElementById("delete"),
  vertexButton: document.getElementById("vertex-mode"),
  message: document.getElementById("edit-message"),
  count: document.getElementById("edit-count"),
  undo: document.getElementById("undo"),
  save: document.getElementById("save"),
  status: document.getElementById("save-status"),
};
const editor = { selected: null, deleted: [], drawn: 0, groups: {}, byId: new Map(), undo: [], listFilled: false };

function classStyle(cls) {
  const c = EDIT.classes[cls];
  return { color: c.stroke, fillColor: c.fill, weight: cls === "street" ? 0.5 : 1, opacity: 1, fillOpacity: 0.85 };
}

function classLabel(cls) {
  const c = EDIT.classes[cls];
  const swatch = `<span class="swatch" style="background:${c.fill};border-color:${c.stroke}"></span>`;
  return `${swatch} ${c.label} (<span class="count-${cls}">${editor.groups[cls].getLayers().length}</span>)`;
}

function refreshCounts() {
  for (const cls of CLASSES) {
    for (const el of document.querySelectorAll(`.count-${cls}`)) el.textContent = editor.groups[cls].getLayers().length;
  }
  const kinds = Object.fromEntries(EDIT_KINDS.map((k) => [k, 0]));
  for (const layer of allLayers()) for (const kind of layer.curbside.edits) kinds[kind] += 1;
  const parts = EDIT_KINDS.filter((k) => kinds[k]).map((k) => `${kinds[k]} ${k}`);
  if (editor.deleted.length) parts.push(`${editor.deleted.length} deleted`);
  ui.count.textContent = parts.length ? `edits: ${parts.join(", ")}` : "no edits yet";
}

function allLayers() {
  return CLASSES.flatMap((cls) => editor.groups[cls].getLayers());
}

function cloneLatLngs(latlngs) {
  return Array.isArray(latlngs) ? latlngs.map(cloneLatLngs) : L.latLng(latlngs.lat, latlngs.lng);
}

// A visible message, read out by screen readers (the element is an aria-live status region).
function say(text, refused = false) {
  ui.message.className = refused ? "refused" : "";
  ui.message.textContent = text;
}

function showGroup(cls) {
  if (!map.hasLayer(editor.groups[cls])) editor.groups[cls].addTo(map);
  return editor.groups[cls];
}

// -- the list of polygons: the keyboard's way to them (the map's canvas has no focusable shapes) ----
function optionText(layer) {
  const c = layer.curbside;
  const where = c.cls === "sidewalk" && c.props.street ? `, ${c.props.street}${c.props.side ? ` (${c.props.side})` : ""}` : "";
  return `${c.id}: ${EDIT.classes[c.cls].label}${where}${c.edits.size ? ", edited" : ""}`;
}

function syncOption(layer, present) {
  const c = layer.curbside;
  if (!editor.listFilled) return;
  if (!present) {
    c.option.remove();
    return;
  }
  c.option.text = optionText(layer);
  if (c.option.parentNode) return;
  const next = [...ui.list.options].find((o) => editor.byId.get(o.value).curbside.order > c.order);
  ui.list.add(c.option, next ?? null);
}

// Filled once the map is drawn, or on the list's first focus if sooner: the 7,600 lines of a whole
// city's map take a list box a few hundred ms to lay out, which should not hold up the map.
function fillList() {
  if (editor.listFilled) return;
  editor.listFilled = true;
  const lines = document.createDocumentFragment();
  for (const layer of allLayers().sort((a, b) => a.curbside.order - b.curbside.order)) {
    layer.curbside.option.text = optionText(layer);
    lines.append(layer.curbside.option);
  }
  ui.list.append(lines);
  ui.list.value = editor.selected ? String(editor.selected.curbside.id) : "";
}

function makeLayer(layer, feature, edits, order) {
  const props = feature.properties;
  const option = new Option("", String(feature.id));
  layer.curbside = { id: feature.id, cls: props.class, props: { ...props }, original: feature, edits: new Set(edits), order, option };
  layer.setStyle(classStyle(props.class));
  layer.on("click", (event) => {
    if (map.pm.globalDrawModeEnabled()) return;  // a click while drawing places a vertex
    L.DomEvent.stopPropagation(event);
    select(layer);
  });
  layer.on("pm:edit", () => commitGeometry(layer));
  layer.on("pm:layerreset", () => say(`polygon ${feature.id}: that move would make its outline cross itself; the vertex went back`, true));
  editor.byId.set(String(feature.id), layer);
  return layer;
}

// -- selection -----------------------------------------------------------------------------------
function showProperties(layer) {
  const c = layer.curbside;
  ui.selectionTitle.textContent = `polygon ${c.id}`;
  ui.selectionState.textContent = c.edits.size
    ? `edited: ${EDIT_KINDS.filter((k) => c.edits.has(k)).join(", ")}` : `as in ${EDIT.source}`;
  ui.featureClass.value = c.cls;
  ui.sidewalkFields.hidden = c.cls !== "sidewalk";
  for (const f of SIDEWALK_FIELDS) ui.fields[f].value = c.props[f] ?? "";
}

function select(layer) {
  if (editor.selected === layer) return;
  deselect();
  editor.selected = layer;
  layer.curbside.latlngs = cloneLatLngs(layer.getLatLngs());  // the outline an undo goes back to
  layer.setStyle(SELECTED_STYLE);
  layer.pm.enable({
    allowSelfIntersection: false, snappable: true, removeLayerBelowMinVertexCount: false,
    removeVertexValidation: vertexRemovable,
  });
  ui.selection.disabled = false;
  showProperties(layer);
  ui.list.value = String(layer.curbside.id);
}

function deselect() {
  const layer = editor.selected;
  if (!layer) return;
  leaveVertexMode(true);
  layer.pm.disable();
  layer.setStyle(classStyle(layer.curbside.cls));
  editor.selected = null;
  ui.selection.disabled = true;
  ui.selectionTitle.textContent = "nothing selected";
  ui.selectionState.textContent = "";
  ui.list.selectedIndex = -1;
}

function selectFromList() {
  const layer = editor.byId.get(ui.list.value);
  if (!layer) return;
  showGroup(layer.curbside.cls);  // its class may be toggled off in the layer control
  select(layer);
  map.fitBounds(layer.getBounds(), { maxZoom: 19, padding: [40, 40], animate: false });
}

// -- edits, each undoable: the edited polygon's state before the edit goes on a stack -----------------
function stateOf(layer) {
  const c = layer.curbside;
  return {
    layer, cls: c.cls, props: { ...c.props }, edits: new Set(c.edits),
    latlngs: c.latlngs ?? cloneLatLngs(layer.getLatLngs()), present: editor.groups[c.cls].hasLayer(layer),
    deleted: [...editor.deleted], drawn: editor.drawn,
  };
}

function remember(what, layer) {
  say("");  // an edit went through: a refusal shown before is stale
  editor.undo.push({ what, state: stateOf(layer) });
  if (editor.undo.length > UNDO_STEPS) editor.undo.shift();
  updateUndoButton();
}

function updateUndoButton() {
  const last = editor.undo[editor.undo.length - 1];
  ui.undo.disabled = !last;
  ui.undo.title = last ? `undo the ${last.what} (Ctrl+Z)` : "nothing to undo";
}

function undo() {
  const step = editor.undo.pop();
  if (!step) {
    say("nothing to undo");
    return;
  }
  const { layer, ...state } = step.state;
  const c = layer.curbside;
  const vertex = vertexMode.layer === layer ? vertexMode.index : null;  // vertex mode goes on after the undo
  deselect();
  editor.groups[c.cls].removeLayer(layer);
  Object.assign(c, { cls: state.cls, props: state.props, edits: state.edits });
  layer.setLatLngs(cloneLatLngs(state.latlngs));
  layer.setStyle(classStyle(c.cls));
  editor.deleted = state.deleted;
  editor.drawn = state.drawn;
  if (state.present) showGroup(c.cls).addLayer(layer);
  syncOption(layer, state.present);
  refreshCounts();
  if (state.present) select(layer);
  const resumed = state.present && vertex !== null && enterVertexMode(vertex, true);
  updateUndoButton();
  say(`undone: ${step.what}${resumed ? `; ${vertexText()}` : ""}`);
}

function markEdited(layer, kind) {
  layer.curbside.edits.add(kind);
  syncOption(layer, true);
  if (editor.selected === layer) showProperties(layer);
  refreshCounts();
}

// A new outline for a polygon being edited (Geoman's vertex handles follow only when re-enabled).
function setOutline(layer, latlngs) {
  layer.pm.disable();
  layer.setLatLngs(cloneLatLngs(latlngs));
  layer.pm.enable();
}

// Every outline edit ends here, a pointer's (Geoman's pm:edit) or the keyboard's (vertex mode).
const REMOVAL_CROSSES = "removing that vertex would make its outline cross itself; it is back";

function commitGeometry(layer, what = "vertex edit", refusal = REMOVAL_CROSSES) {
  const c = layer.curbside;
  // Geoman puts back a vertex removal that makes the outline cross itself only after announcing it as an
  // edit, and silently: refuse it here, before it counts as one.
  const crossing = layer.pm.hasSelfIntersection();
  if (crossing) {
    setOutline(layer, c.latlngs);
    say(`polygon ${c.id}: ${refusal}`, true);
  } else {
    remember(`${what} of polygon ${c.id}`, layer);
    c.latlngs = cloneLatLngs(layer.getLatLngs());
    markEdited(layer, "geometry");
  }
  if (vertexMode.layer === layer) showVertex();
  return !crossing;
}

const TOO_FEW_VERTICES = "a ring keeps at least 3 vertices (to remove the polygon, delete it)";

function vertexRemovable({ layer, marker }) {
  const { parentPath } = L.PM.Utils.findDeepMarkerIndex(layer.pm._markers, marker);
  const ring = parentPath.reduce((latlngs, i) => latlngs[i], layer.getLatLngs());
  if (ring.length > 3) return true;
  say(`polygon ${layer.curbside.id}: ${TOO_FEW_VERTICES}`, true);
  return false;
}

function setClass(layer, cls) {
  const c = layer.curbside;
  if (c.cls === cls) return;
  remember(`class change of polygon ${c.id}`, layer);
  editor.groups[c.cls].removeLayer(layer);
  c.cls = cls;
  c.props.class = cls;
  showGroup(cls).addLayer(layer);
  layer.setStyle(editor.selected === layer ? SELECTED_STYLE : classStyle(cls));
  markEdited(layer, "class");
}

function setField(layer, field, value) {
  const c = layer.curbside;
  if ((c.props[field] ?? "") === value) return;
  remember(`${field} change of polygon ${c.id}`, layer);
  c.props[field] = value;
  markEdited(layer, "fields");
}

function removeSelected() {
  const layer = editor.selected;
  if (!layer) return;
  const c = layer.curbside;
  remember(`deletion of polygon ${c.id}`, layer);
  deselect();
  editor.groups[c.cls].removeLayer(layer);
  if (typeof c.id === "number") editor.deleted.push(c.id);
  syncOption(layer, false);
  refreshCounts();
  say(`polygon ${c.id} deleted (undo brings it back)`);
}

function addDrawn(event) {
  const cls = ui.drawClass.value;
  const id = `new-${editor.drawn + 1}`;
  map.removeLayer(event.layer);
  const feature = { id, properties: { class: cls }, geometry: null };
  const layer = makeLayer(L.polygon(event.layer.getLatLngs()), feature, ["drawn"], EDIT.features.length + editor.drawn);
  remember(`drawing of polygon ${id}`, layer);
  editor.drawn += 1;
  showGroup(cls).addLayer(layer);
  syncOption(layer, true);
  refreshCounts();
  select(layer);
}

// -- saving --------------------------------------------------------------------------------------
function ringOk(ring) {
  const distinct = new Set(ring.map((p) => `${p[0]},${p[1]}`));
  return distinct.size >= 3;
}

function featureOf(layer) {
  const c = layer.curbside;
  if (!c.edits.size) return c.original;  // as in the map file, byte for byte once serialised
  const props = { class: c.cls };
  if (c.cls === "sidewalk") {
    for (const f of SIDEWALK_FIELDS) props[f] = c.props[f] === "" ? null : (c.props[f] ?? null);
    if (!props.segment_id) props.segment_id = `hand-${c.id}`;
    // The build's bearing from the street holds through a reshape, not once the side is changed.
    const before = c.original.properties || {};
    if (typeof before.facing_deg === "number" && before.side === props.side) props.facing_deg = before.facing_deg;
  }
  props.edited = EDIT_KINDS.filter((k) => c.edits.has(k)).join(",");
  const geometry = c.edits.has("geometry") || c.edits.has("drawn")
    ? layer.toGeoJSON(EDIT.decimals).geometry : c.original.geometry;
  const rings = geometry.type === "Polygon" ? geometry.coordinates : geometry.coordinates.flat();
  if (!rings.every(ringOk)) throw new Error(`polygon ${c.id} has a ring of fewer than 3 distinct vertices`);
  return { type: "Feature", id: c.id, properties: props, geometry };
}

// The file's order: its features by index (shown or kept), then the drawn ones (new-1, new-2...).
function fileOrder(a, b) {
  const drawn = (f) => typeof f.id !== "number";
  if (drawn(a) !== drawn(b)) return drawn(a) ? 1 : -1;
  return drawn(a) ? Number(a.id.slice(4)) - Number(b.id.slice(4)) : a.id - b.id;
}

function editedDocument() {
  const kept = JSON.parse(document.getElementById("edit-kept").textContent);
  const features = [...allLayers().map(featureOf), ...kept].sort(fileOrder);
  const ids = (kind) => allLayers().filter((l) => l.curbside.edits.has(kind)).map((l) => l.curbside.id);
  const edits = { from: EDIT.source, editor: EDIT.generator, saved: new Date().toISOString(), window: EDIT.window };
  for (const kind of EDIT_KINDS) edits[kind] = ids(kind);
  edits.deleted = [...editor.deleted].sort((a, b) => a - b);
  return { type: "FeatureCollection", curbside: { ...EDIT.meta, edits }, features };
}

function save() {
  let text;
  try {
    text = JSON.stringify(editedDocument());
  } catch (error) {
    ui.status.className = "error";
    ui.status.textContent = `not saved: ${error.message}`;
    return;
  }
  const url = URL.createObjectURL(new Blob([text], { type: "application/geo+json" }));
  const link = document.createElement("a");
  link.href = url;
  link.download = EDIT.filename;
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
  ui.status.className = "";
  ui.status.textContent = `saved as ${EDIT.filename} (your downloads folder)`;
}

// -- keyboard and accessible names -----------------------------------------------------------------
function onKey(event) {
  const focus = document.activeElement;
  const onMapOrList = focus === map.getContainer() || focus === ui.list;
  if ((event.ctrlKey || event.metaKey) && !event.altKey && !event.shiftKey && event.key.toLowerCase() === "z") {
    if (focus.tagName === "INPUT") return;  // the text field's own undo
    event.preventDefault();
    undo();
  } else if ((event.key === "Delete" || event.key === "Backspace") && onMapOrList) {
    event.preventDefault();
    removeSelected();
  } else if (event.key === "Escape" && (onMapOrList || focus === document.body)) {
    deselect();
  } else if (event.key.toLowerCase() === "v" && onMapOrList && !event.ctrlKey && !event.metaKey && !event.altKey) {
    event.preventDefault();  // not the list's type-ahead
    enterVertexMode();
  }
}

// Leaflet-Geoman titles the draw buttons' container, not the buttons; its vertex handles are markers
// that Leaflet makes tab stops without a name (out of the tab order: vertex mode is the keyboard's way).
function nameControls() {
  for (const container of document.querySelectorAll(".leaflet-pm-toolbar .button-container")) {
    const button = container.querySelector(".leaflet-buttons-control-button");
    if (button && container.title) button.setAttribute("aria-label", `${container.title} (of the class chosen in "new polygons are")`);
  }
}

function nameHandles() {
  for (const handle of map.getPane("markerPane").querySelectorAll(".marker-icon:not([aria-label])")) {
    const middle = handle.classList.contains("marker-icon-middle");
    handle.setAttribute("aria-label", middle ? "mid-point: drag to add a vertex" : "vertex: drag to move, right-click to remove");
    handle.setAttribute("tabindex", "-1");
  }
}

// -- set-up --------------------------------------------------------------------------------------
for (const cls of CLASSES) {
  editor.groups[cls] = L.featureGroup().addTo(map);
  for (const select of [ui.drawClass, ui.featureClass]) select.add(new Option(EDIT.classes[cls].label, cls));
}
EDIT.features.forEach((feature, order) => {
  const layer = makeLayer(L.GeoJSON.geometryToLayer(feature), feature, [], order);
  editor.groups[feature.properties.class].addLayer(layer);
});
for (const cls of CLASSES) layers.addOverlay(editor.groups[cls], classLabel(cls));
ui.drawClass.value = "sidewalk";
ui.source.textContent = EDIT.window
  ? `editing ${EDIT.source}: the ${EDIT.features.length} polygons that meet the window (dashed; `
    + `${EDIT.kept_count.toLocaleString("en")} more saved as they are)`
  : `editing ${EDIT.source} (${EDIT.features.length.toLocaleString("en")} polygons)`;
if (EDIT.window) {
  const [west, south, east, north] = EDIT.window;
  L.rectangle([[south, west], [north, east]], { color: "#333", weight: 1.5, dashArray: "6 4", fill: false, interactive: false, pmIgnore: true }).addTo(map);
}

map.pm.addControls({
  position: "topleft", drawMarker: false, drawCircleMarker: false, drawPolyline: false, drawCircle: false,
  drawText: false, editMode: false, dragMode: false, cutPolygon: false, removalMode: false, rotateMode: false,
});
map.pm.setGlobalOptions({ allowSelfIntersection: false });
nameControls();
new MutationObserver(nameHandles).observe(map.getPane("markerPane"), { childList: true });
map.on("pm:create", addDrawn);
map.createPane("currentVertex").style.zIndex = 650;  // vertex mode's highlight, over Geoman's handles
map.on("pm:globaldrawmodetoggled", () => leaveVertexMode(true));
map.on("click", deselect);
ui.list.addEventListener("focus", fillList);
requestAnimationFrame(() => setTimeout(fillList));
ui.list.addEventListener("change", selectFromList);
ui.featureClass.addEventListener("change", () => editor.selected && setClass(editor.selected, ui.featureClass.value));
for (const f of SIDEWALK_FIELDS) {
  ui.fields[f].addEventListener("change", () => editor.selected && setField(editor.selected, f, ui.fields[f].value));
}
ui.remove.addEventListener("click", () => {
  removeSelected();
  ui.list.focus();  // the button is disabled with nothing selected: keep the focus somewhere useful
});
ui.vertexButton.addEventListener("click", () => (vertexMode.layer ? leaveVertexMode() : enterVertexMode()));
ui.undo.addEventListener("click", undo);
ui.save.addEventListener("click", save);
window.addEventListener("keydown", onVertexKey, true);  // capture: before onKey and Leaflet's keyboard
document.addEventListener("keydown", onKey);
refreshCounts();
updateUndoButton();
window.curbsideEditor = { editor, select, undo, editedDocument };
performance.mark("curbside:editor-ready");
