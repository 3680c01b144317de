// curbside map editor. Runs after the page skeleton of curbside/osmseg/webmap.py has created `map` and
// `layers`, with Leaflet-Geoman loaded and `EDIT` = {source, filename, generator, meta, classes,
// decimals, features} inlined by curbside/osmseg/edit.py.

const CLASSES = Object.keys(EDIT.classes);
const SIDEWALK_FIELDS = ["segment_id", "street", "side"];
const EDIT_KINDS = ["geometry", "class", "fields", "drawn"];
const SELECTED_STYLE = { color: "#00a5c8", weight: 3, opacity: 1 };
const ui = {
  source: document.getElementById("edit-source"),
  drawClass: document.getElementById("draw-class"),
  selection: document.getElementById("selection"),
  selectionTitle: document.getElementById("selection-title"),
  featureClass: document.getElementById("feature-class"),
  sidewalkFields: document.getElementById("sidewalk-fields"),
  fields: Object.fromEntries(SIDEWALK_FIELDS.map((f) => [f, document.getElementById(`field-${f}`)])),
  remove: document.getElementById("delete"),
  count: document.getElementById("edit-count"),
  save: document.getElementById("save"),
  status: document.getElementById("save-status"),
};
const editor = { selected: null, deleted: [], drawn: 0, groups: {}, labels: {} };

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

function markEdited(layer, kind) {
  layer.curbside.edits.add(kind);
  refreshCounts();
}

function addFeatureLayer(layer, feature, edits) {
  const props = feature.properties;
  layer.curbside = { id: feature.id, cls: props.class, props: { ...props }, original: feature, edits: new Set(edits) };
  layer.setStyle(classStyle(props.class));
  layer.on("click", (event) => {
    if (map.pm.globalDrawModeEnabled()) return;  // a click while drawing places a vertex
    L.DomEvent.stopPropagation(event);
    select(layer);
  });
  layer.on("pm:edit", () => markEdited(layer, "geometry"));
  editor.groups[props.class].addLayer(layer);
  return layer;
}

// -- selection -----------------------------------------------------------------------------------
function select(layer) {
  if (editor.selected === layer) return;
  deselect();
  editor.selected = layer;
  layer.setStyle(SELECTED_STYLE);
  layer.pm.enable({ allowSelfIntersection: false, snappable: true });
  const c = layer.curbside;
  ui.selection.disabled = false;
  ui.selectionTitle.textContent = `polygon ${c.id}`;
  ui.featureClass.value = c.cls;
  ui.sidewalkFields.hidden = c.cls !== "sidewalk";
  for (const f of SIDEWALK_FIELDS) ui.fields[f].value = c.props[f] ?? "";
}

function deselect() {
  const layer = editor.selected;
  if (!layer) return;
  layer.pm.disable();
  layer.setStyle(classStyle(layer.curbside.cls));
  editor.selected = null;
  ui.selection.disabled = true;
  ui.selectionTitle.textContent = "nothing selected";
}

function setClass(layer, cls) {
  const c = layer.curbside;
  if (c.cls === cls) return;
  editor.groups[c.cls].removeLayer(layer);
  c.cls = cls;
  c.props.class = cls;
  editor.groups[cls].addLayer(layer);
  if (!map.hasLayer(editor.groups[cls])) editor.groups[cls].addTo(map);
  layer.setStyle(editor.selected === layer ? SELECTED_STYLE : classStyle(cls));
  ui.sidewalkFields.hidden = cls !== "sidewalk";
  markEdited(layer, "class");
}

function removeSelected() {
  const layer = editor.selected;
  if (!layer) return;
  deselect();
  editor.groups[layer.curbside.cls].removeLayer(layer);
  if (typeof layer.curbside.id === "number") editor.deleted.push(layer.curbside.id);
  refreshCounts();
}

// -- saving --------------------------------------------------------------------------------------
function ringOk(ring) {
  const distinct = new Set(ring.map((p) => `${p[0]},${p[1]}`));
  return distinct.size >= 3;
}

function featureOf(layer) {
  const c = layer.curbside;
  const props = { class: c.cls };
  if (c.cls === "sidewalk") {
    for (const f of SIDEWALK_FIELDS) props[f] = c.props[f] === "" ? null : (c.props[f] ?? null);
    if (!props.segment_id) props.segment_id = `hand-${c.id}`;
  }
  if (c.edits.size) props.edited = EDIT_KINDS.filter((k) => c.edits.has(k)).join(",");
  const geometry = c.edits.has("geometry") || c.edits.has("drawn")
    ? layer.toGeoJSON(EDIT.decimals).geometry : c.original.geometry;
  const rings = geometry.type === "Polygon" ? geometry.coordinates : geometry.coordinates.flat();
  if (!rings.every(ringOk)) throw new Error(`polygon ${c.id} has a ring of fewer than 3 distinct vertices`);
  return { type: "Feature", id: c.id, properties: props, geometry };
}

function editedDocument() {
  const features = allLayers().map(featureOf);
  const ids = (kind) => allLayers().filter((l) => l.curbside.edits.has(kind)).map((l) => l.curbside.id);
  const edits = { from: EDIT.source, editor: EDIT.generator, saved: new Date().toISOString() };
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

// -- set-up --------------------------------------------------------------------------------------
for (const cls of CLASSES) {
  editor.groups[cls] = L.featureGroup().addTo(map);
  for (const select of [ui.drawClass, ui.featureClass]) select.add(new Option(EDIT.classes[cls].label, cls));
}
for (const feature of EDIT.features) {
  addFeatureLayer(L.GeoJSON.geometryToLayer(feature), feature, []);
}
for (const cls of CLASSES) layers.addOverlay(editor.groups[cls], classLabel(cls));
ui.drawClass.value = "sidewalk";
ui.source.textContent = `editing ${EDIT.source} (${EDIT.features.length} polygons)`;

map.pm.addControls({
  position: "topleft", drawMarker: false, drawCircleMarker: false, drawPolyline: false, drawCircle: false,
  drawText: false, editMode: false, dragMode: false, cutPolygon: false, removalMode: false, rotateMode: false,
});
map.pm.setGlobalOptions({ allowSelfIntersection: false });
map.on("pm:create", (event) => {
  editor.drawn += 1;
  const cls = ui.drawClass.value;
  const feature = { id: `new-${editor.drawn}`, properties: { class: cls }, geometry: null };
  map.removeLayer(event.layer);
  const layer = L.polygon(event.layer.getLatLngs());
  addFeatureLayer(layer, feature, ["drawn"]);
  refreshCounts();
  select(layer);
});
map.on("click", deselect);
ui.featureClass.addEventListener("change", () => editor.selected && setClass(editor.selected, ui.featureClass.value));
for (const f of SIDEWALK_FIELDS) {
  ui.fields[f].addEventListener("change", () => {
    if (!editor.selected) return;
    editor.selected.curbside.props[f] = ui.fields[f].value;
    markEdited(editor.selected, "fields");
  });
}
ui.remove.addEventListener("click", removeSelected);
ui.save.addEventListener("click", save);
document.addEventListener("keydown", (event) => {
  if (["INPUT", "SELECT"].includes(event.target.tagName)) return;
  if (event.key === "Delete") removeSelected();
  if (event.key === "Escape") deselect();
});
refreshCounts();
window.curbsideEditor = { editor, select, editedDocument };
performance.mark("curbside:editor-ready");
