// approxtree web viewer: loads CesiumJS, then a 3D Tiles tileset or a quantized-mesh terrain
// with imagery draped over it, chosen by URL parameters (see index.html). It reaches no server
// but the ones named in the URL: no Cesium ion token, no geocoder. Tests read
// window.approxtree.
"use strict";

// Where CesiumJS comes from: the `cesium` parameter, else the repository's npm copy, else this
// CDN (change it here to pin another version or mirror).
const CDN_CESIUM = "https://cdn.jsdelivr.net/npm/cesium@1.140.0/Build/Cesium/";
const LOCAL_CESIUM = "../../web/node_modules/cesium/Build/Cesium/";

const params = new URLSearchParams(window.location.search);
const status = document.getElementById("status");

// What the browser test reads: ready once the tiles are loaded and a few frames have passed.
window.approxtree = { ready: false, error: null, frames: 0 };

function fail(message) {
  window.approxtree.error = String(message);
  status.textContent = "Error: " + message;
  console.error(message);
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

function loadScript(src) {
  return new Promise((resolve, reject) => {
    const s = document.createElement("script");
    s.src = src;
    s.onload = resolve;
    s.onerror = () => reject(new Error("cannot load " + src));
    document.head.appendChild(s);
  });
}

async function loadCesium() {
  const bases = params.has("cesium") ? [params.get("cesium")] : [LOCAL_CESIUM, CDN_CESIUM];
  for (const base of bases) {
    const url = new URL(base.endsWith("/") ? base : base + "/", window.location.href).href;
    window.CESIUM_BASE_URL = url;
    try {
      await loadScript(url + "Cesium.js");
    } catch (e) {
      continue;
    }
    const css = document.createElement("link");
    css.rel = "stylesheet";
    css.href = url + "Widgets/widgets.css";
    document.head.appendChild(css);
    return url;
  }
  throw new Error("CesiumJS not found at " + bases.join(" or ") + "; pass ?cesium=URL");
}

// Triangles drawn this frame: the tileset's selected contents, or the globe's rendered tiles
// (their meshes' indices, skirts included, and without them).
function statistics(viewer, tileset) {
  const cam = viewer.scene.camera;
  const xyz = (v) => [v.x, v.y, v.z];
  const out = {
    frames: window.approxtree.frames,
    camera: {
      position: xyz(cam.positionWC),
      direction: xyz(cam.directionWC),
      up: xyz(cam.upWC),
      fov: cam.frustum.fov,
      near: cam.frustum.near,
      far: cam.frustum.far,
    },
  };
  if (tileset) {
    const s = tileset.statistics;
    const selected = tileset._selectedTiles;
    out.tileset = {
      selected: s.selected,
      visited: s.visited,
      triangles: s.numberOfTrianglesSelected,
      commands: s.numberOfCommands,
      tilesLoaded: s.numberOfLoadedTilesTotal,
      geometryBytes: s.geometryByteLength,
      texturesBytes: s.texturesByteLength,
      selectedDepths: selected.map((t) => t._depth),
      selectedErrors: selected.map((t) => t.geometricError),
    };
  }
  const surface = viewer.scene.globe._surface;
  if (viewer.scene.globe.show && surface) {
    let triangles = 0;
    let withoutSkirts = 0;
    const levels = [];
    for (const tile of surface._tilesToRender) {
      const mesh = tile.data && tile.data.renderedMesh;
      levels.push(tile.level);
      if (!mesh) continue;
      triangles += mesh.indices.length / 3;
      withoutSkirts += mesh.indexCountWithoutSkirts / 3;
    }
    out.globe = { tiles: levels.length, triangles, trianglesWithoutSkirts: withoutSkirts, levels };
  }
  return out;
}

// The imagery of `approxtree tiles --format imagery` (or of approxtree serve): its TileJSON
// names the tiling (geographic TMS or Web Mercator XYZ), the zooms and the bounds.
async function imageryProvider(C, url) {
  const address = new URL(url, window.location.href);
  const doc = await (await fetch(address)).json();
  const meta = doc.approxtree || {};
  // Resolved by hand: new URL() would percent-encode the template's braces.
  const template = doc.tiles[0];
  const folder = address.href.slice(0, address.href.lastIndexOf("/") + 1);
  let tiles = /^https?:/.test(template) ? template : folder + template;
  // TMS rows count from the south: Cesium's {reverseY}.
  if (doc.scheme === "tms") tiles = tiles.replace("{y}", "{reverseY}");
  const size = meta.tile_size || 256;
  return new C.UrlTemplateImageryProvider({
    url: tiles,
    tilingScheme:
      meta.tiling === "webmercator" ? new C.WebMercatorTilingScheme() : new C.GeographicTilingScheme(),
    rectangle: C.Rectangle.fromDegrees(...doc.bounds),
    minimumLevel: 0,
    maximumLevel: doc.maxzoom,
    tileWidth: size,
    tileHeight: size,
  });
}

// The default camera over a terrain: from the south, 35° down onto the centre of its bounds,
// far enough to hold them (an oblique view, so the relief shows, not a flat map).
function obliqueView(C, scene, bounds) {
  const rect = C.Rectangle.fromDegrees(...bounds);
  const centre = C.Rectangle.center(rect);
  const corner = C.Cartesian3.fromRadians(rect.west, rect.south);
  const target = C.Cartesian3.fromRadians(centre.longitude, centre.latitude);
  const range = 1.6 * C.Cartesian3.distance(corner, target);
  scene.camera.lookAt(target, new C.HeadingPitchRange(0.0, C.Math.toRadians(-35.0), range));
  scene.camera.lookAtTransform(C.Matrix4.IDENTITY);
}

async function main() {
  const base = await loadCesium();
  const C = window.Cesium;
  const tilesetUrl = params.get("tileset");
  const terrainUrl = params.get("terrain");
  if (!tilesetUrl && !terrainUrl) {
    throw new Error("give ?tileset=URL/tileset.json or ?terrain=URL (a folder with layer.json)");
  }
  const sse = params.has("sse") ? Number(params.get("sse")) : null;
  const imageryUrl = params.get("imagery");
  const bg = params.get("bg");

  // Terrain: the quantized-mesh folder, else the plain ellipsoid (never Cesium ion's).
  // CesiumJS reads the tiles' metadata extension only for layers that give their availability
  // per tile (metadataAvailability); with a full "available" list in layer.json it fails on
  // it (CesiumTerrainProvider: layer.availabilityTilesLoaded undefined), so it is asked for
  // only then.
  let layer = null;
  if (terrainUrl) {
    const folder = new URL(terrainUrl.replace(/\/?$/, "/"), window.location.href);
    layer = await (await fetch(new URL("layer.json", folder))).json();
  }
  const terrainProvider = terrainUrl
    ? await C.CesiumTerrainProvider.fromUrl(terrainUrl, {
        requestVertexNormals: true,
        requestMetadata: layer.metadataAvailability !== undefined,
      })
    : new C.EllipsoidTerrainProvider();

  const viewer = new C.Viewer("view", {
    baseLayer: false,
    terrainProvider,
    animation: false,
    timeline: false,
    geocoder: false,
    baseLayerPicker: false,
    homeButton: false,
    sceneModePicker: false,
    navigationHelpButton: false,
    fullscreenButton: false,
    infoBox: false,
    selectionIndicator: false,
    creditContainer: document.getElementById("credits"),
    msaaSamples: 1,
    contextOptions: { webgl: { preserveDrawingBuffer: true } },
  });
  const scene = viewer.scene;
  // A plain scene: no sky, sun, fog or atmosphere, so pixels are terrain or background and
  // tile selection depends on the screen-space error alone.
  scene.skyBox.show = false;
  scene.skyAtmosphere.show = false;
  scene.sun.show = false;
  scene.moon.show = false;
  scene.fog.enabled = false;
  scene.globe.showGroundAtmosphere = false;
  scene.globe.enableLighting = false;
  scene.postProcessStages.fxaa.enabled = false;
  scene.globe.baseColor = terrainUrl ? C.Color.fromCssColorString("#d8d0c0") : C.Color.GRAY;
  scene.backgroundColor = bg ? C.Color.fromCssColorString(bg) : C.Color.BLACK;
  viewer.resolutionScale = 1.0;
  viewer.useBrowserRecommendedResolution = false;
  if (params.get("globe") === "0") scene.globe.show = false;
  if (params.has("exaggeration")) scene.verticalExaggeration = Number(params.get("exaggeration"));
  let imagery = null;
  if (imageryUrl) {
    imagery = viewer.imageryLayers.addImageryProvider(await imageryProvider(C, imageryUrl));
  }
  if (sse !== null) scene.globe.maximumScreenSpaceError = sse;
  const clip = numbers("clip", 4);
  if (clip) scene.globe.cartographicLimitRectangle = C.Rectangle.fromDegrees(...clip);

  let tileset = null;
  if (tilesetUrl) {
    tileset = await C.Cesium3DTileset.fromUrl(tilesetUrl, sse !== null ? { maximumScreenSpaceError: sse } : {});
    scene.primitives.add(tileset);
  }

  // The camera: given in ECEF, else fitted to the content.
  const pos = numbers("pos", 3);
  if (pos) {
    const dir = numbers("dir", 3) || [0, 0, -1];
    const up = numbers("up", 3) || [0, 0, 1];
    scene.camera.setView({
      destination: new C.Cartesian3(...pos),
      orientation: { direction: new C.Cartesian3(...dir), up: new C.Cartesian3(...up) },
    });
  } else if (tileset) {
    await viewer.zoomTo(tileset);
  } else {
    obliqueView(C, scene, layer.bounds || [-180, -90, 180, 90]);
  }
  // Cesium's fov is the horizontal one when the canvas is wider than high; ours is vertical.
  const vfov = params.has("vfov") ? Number(params.get("vfov")) : null;
  const near = params.has("near") ? Number(params.get("near")) : null;
  const frustum = scene.camera.frustum;
  if (near !== null) frustum.near = near;

  scene.preRender.addEventListener(() => {
    if (vfov === null) return;
    const aspect = scene.canvas.clientWidth / scene.canvas.clientHeight;
    const half = C.Math.toRadians(vfov) / 2;
    frustum.fov = aspect > 1 ? 2 * Math.atan(Math.tan(half) * aspect) : 2 * half;
  });

  // Shading: a fixed light from the north-west, 35° high at the camera's place (not the sun of
  // the clock's time), so the relief shows the same at any hour; light=0 leaves it unlit, and
  // so does draped imagery (a baked shading carries its own light) unless light=1.
  const light = params.has("light") ? params.get("light") !== "0" : !imageryUrl;
  if (light) {
    const enu = C.Transforms.eastNorthUpToFixedFrame(scene.camera.positionWC);
    const alt = C.Math.toRadians(35.0);
    const toLight = new C.Cartesian3(
      -Math.cos(alt) * Math.SQRT1_2,
      Math.cos(alt) * Math.SQRT1_2,
      Math.sin(alt),
    );
    const dir = C.Matrix4.multiplyByPointAsVector(enu, toLight, new C.Cartesian3());
    scene.light = new C.DirectionalLight({
      direction: C.Cartesian3.normalize(C.Cartesian3.negate(dir, dir), new C.Cartesian3()),
    });
    scene.globe.enableLighting = true;
    scene.globe.dynamicAtmosphereLighting = false;
    // Cesium fades the globe's shading out nearer than lightingFadeOutDistance: keep it.
    scene.globe.lightingFadeOutDistance = 0.0;
    scene.globe.lightingFadeInDistance = 1.0;
  }

  let loadedFrames = 0;
  scene.postRender.addEventListener(() => {
    window.approxtree.frames += 1;
    const loaded = tileset ? tileset.tilesLoaded : scene.globe.tilesLoaded;
    loadedFrames = loaded ? loadedFrames + 1 : 0;
    // A few loaded frames in a row: nothing more is coming for this view.
    if (loadedFrames >= 5 && !window.approxtree.ready) {
      window.approxtree.stats = statistics(viewer, tileset);
      window.approxtree.ready = true;
      status.textContent = "";
    }
  });
  window.approxtree.viewer = viewer;
  window.approxtree.tileset = tileset;
  window.approxtree.imagery = imagery;
  window.approxtree.statistics = () => statistics(viewer, tileset);
  window.approxtree.cesiumBase = base;
  status.textContent = "loading tiles…";
}

main().catch((e) => fail(e && e.message ? e.message : e));
