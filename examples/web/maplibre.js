// approxtree raster-dem in MapLibre GL JS (see maplibre.html): a style made from the tiles'
// own TileJSON (the PMTiles metadata, or tilejson.json), 3D terrain, a hillshade layer and
// optional imagery. It reaches no server but the ones named in the URL. Tests read
// window.approxtree (ready, error, statistics()).

const params = new URLSearchParams(window.location.search);
const status = document.getElementById("status");
window.approxtree = { ready: false, error: null };

function fail(message) {
  window.approxtree.error = String(message);
  status.textContent = "Error: " + message;
  console.error(message);
}

function loadScript(src) {
  return new Promise((resolve, reject) => {
    const s = document.createElement("script");
    s.src = src;
    s.onload = resolve;
    s.onerror = () => reject(new Error("cannot load " + src));
    document.head.appendChild(s);
  });
}

// A MapLibre source for tiles at `url`, and their TileJSON: a .pmtiles archive through the
// pmtiles protocol (its metadata is approxtree's TileJSON), else a tilejson.json whose
// relative template is resolved here.
async function describe(url) {
  const address = new URL(url, window.location.href).href;
  if (address.endsWith(".pmtiles")) {
    const archive = new window.pmtiles.PMTiles(address);
    return { spec: { url: "pmtiles://" + address }, doc: await archive.getMetadata() };
  }
  const doc = await (await fetch(address)).json();
  const folder = address.slice(0, address.lastIndexOf("/") + 1);
  const tiles = doc.tiles.map((t) => (/^https?:/.test(t) ? t : folder + t));
  const spec = { tiles, minzoom: doc.minzoom, maxzoom: doc.maxzoom, bounds: doc.bounds };
  return { spec, doc };
}

function numbers(name, count) {
  const raw = params.get(name);
  if (raw === null) return null;
  const v = raw.split(",").map(Number);
  if (v.length !== count || v.some((x) => !Number.isFinite(x))) {
    throw new Error(`${name} must be ${count} comma-separated numbers, got ${raw}`);
  }
  return v;
}

async function main() {
  if (!params.get("dem")) throw new Error("give ?dem=URL (a .pmtiles or a tilejson.json)");
  const npm = new URL(params.get("npm") || "../../web/node_modules/", window.location.href).href;
  const css = document.createElement("link");
  css.rel = "stylesheet";
  css.href = npm + "maplibre-gl/dist/maplibre-gl.css";
  document.head.appendChild(css);
  await loadScript(npm + "pmtiles/dist/pmtiles.js");
  const module = await import(npm + "maplibre-gl/dist/maplibre-gl.mjs");
  const maplibregl = module.default || module;
  const protocol = new window.pmtiles.Protocol();
  maplibregl.addProtocol("pmtiles", protocol.tile);

  const dem = await describe(params.get("dem"));
  const meta = dem.doc.approxtree || {};
  const demSource = {
    type: "raster-dem",
    ...dem.spec,
    tileSize: meta.tile_size || 512,
    encoding: meta.maplibre_encoding || "terrarium",
  };
  // Terrain and hillshade from two sources of the same tiles, as MapLibre advises.
  const sources = { terrain: demSource, hills: { ...demSource } };
  const layers = [{ id: "background", type: "background", paint: { "background-color": "#f4f1ea" } }];
  if (params.get("imagery")) {
    const imagery = await describe(params.get("imagery"));
    const size = (imagery.doc.approxtree || {}).tile_size || 256;
    sources.imagery = { type: "raster", ...imagery.spec, tileSize: size };
    layers.push({ id: "imagery", type: "raster", source: "imagery" });
  }
  layers.push({
    id: "hillshade",
    type: "hillshade",
    source: "hills",
    paint: { "hillshade-exaggeration": 0.6, "hillshade-shadow-color": "#473b24" },
  });
  const [west, south, east, north] = dem.doc.bounds;
  const center = numbers("center", 2) || [(west + east) / 2, (south + north) / 2];
  const exaggeration = params.has("exaggeration") ? Number(params.get("exaggeration")) : 1.5;
  const map = new maplibregl.Map({
    container: "map",
    style: { version: 8, sources, layers, terrain: { source: "terrain", exaggeration } },
    center,
    zoom: params.has("zoom") ? Number(params.get("zoom")) : Math.max(dem.doc.maxzoom - 2, 0),
    pitch: params.has("pitch") ? Number(params.get("pitch")) : 60,
    bearing: params.has("bearing") ? Number(params.get("bearing")) : 0,
    maxPitch: 85,
    attributionControl: false,
    fadeDuration: 0,
    canvasContextAttributes: { preserveDrawingBuffer: true },
  });
  map.on("error", (e) => fail(e.error ? e.error.message : e));
  const statistics = () => ({
    zoom: map.getZoom(),
    pitch: map.getPitch(),
    center: map.getCenter().toArray(),
    terrain: map.getTerrain(),
    exaggeration,
    // Metres at the centre as the terrain is drawn (exaggeration included).
    elevation: map.queryTerrainElevation(map.getCenter()),
    layers: map.getStyle().layers.map((l) => l.id),
    loaded: map.areTilesLoaded(),
  });
  window.approxtree.map = map;
  window.approxtree.statistics = statistics;
  map.once("idle", () => {
    window.approxtree.stats = statistics();
    window.approxtree.ready = true;
    status.textContent = "";
  });
  status.textContent = "loading tiles…";
}

main().catch((e) => fail(e && e.message ? e.message : e));
