// 3D Tiles terrain in CesiumJS (Cesium3DTilesTerrainProvider) with a picture draped over it;
// window.approxtree = {ready, error, statistics()} as examples/web/viewer.js.
"use strict";

const params = new URLSearchParams(window.location.search);
window.approxtree = { ready: false, error: null, frames: 0 };

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

async function main() {
  const base = params.get("cesium") || "/cesium/";
  window.CESIUM_BASE_URL = new URL(base, window.location.href).href;
  await loadScript(window.CESIUM_BASE_URL + "Cesium.js");
  const css = document.createElement("link");
  css.rel = "stylesheet";
  css.href = window.CESIUM_BASE_URL + "Widgets/widgets.css";
  document.head.appendChild(css);
  const C = window.Cesium;
  const terrainProvider = await C.Cesium3DTilesTerrainProvider.fromUrl(params.get("terrain"), {
    requestVertexNormals: true,
  });
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
  scene.skyBox.show = false;
  scene.skyAtmosphere.show = false;
  scene.sun.show = false;
  scene.moon.show = false;
  scene.fog.enabled = false;
  scene.globe.showGroundAtmosphere = false;
  scene.postProcessStages.fxaa.enabled = false;
  scene.globe.baseColor = C.Color.GRAY;
  scene.backgroundColor = C.Color.fromCssColorString(params.get("bg") || "#000000");
  viewer.resolutionScale = 1.0;
  viewer.useBrowserRecommendedResolution = false;
  if (params.has("sse")) scene.globe.maximumScreenSpaceError = Number(params.get("sse"));
  const clip = numbers("clip", 4);
  if (clip) scene.globe.cartographicLimitRectangle = C.Rectangle.fromDegrees(...clip);
  const rect = numbers("rect", 4);
  if (params.has("image")) {
    const imagery = await C.SingleTileImageryProvider.fromUrl(params.get("image"), {
      rectangle: C.Rectangle.fromDegrees(...rect),
    });
    viewer.imageryLayers.addImageryProvider(imagery);
  }
  const pos = numbers("pos", 3);
  scene.camera.setView({
    destination: new C.Cartesian3(...pos),
    orientation: {
      direction: new C.Cartesian3(...(numbers("dir", 3) || [0, 0, -1])),
      up: new C.Cartesian3(...(numbers("up", 3) || [0, 0, 1])),
    },
  });
  const vfov = params.has("vfov") ? Number(params.get("vfov")) : null;
  scene.preRender.addEventListener(() => {
    if (vfov === null) return;
    const aspect = scene.canvas.clientWidth / scene.canvas.clientHeight;
    const half = C.Math.toRadians(vfov) / 2;
    scene.camera.frustum.fov = aspect > 1 ? 2 * Math.atan(Math.tan(half) * aspect) : 2 * half;
  });
  // Shading from a fixed light (north-west, 35° high), so the relief shows under the picture.
  const enu = C.Transforms.eastNorthUpToFixedFrame(scene.camera.positionWC);
  const alt = C.Math.toRadians(35.0);
  const toLight = new C.Cartesian3(-Math.cos(alt) * Math.SQRT1_2, Math.cos(alt) * Math.SQRT1_2, Math.sin(alt));
  const dir = C.Matrix4.multiplyByPointAsVector(enu, toLight, new C.Cartesian3());
  scene.light = new C.DirectionalLight({
    direction: C.Cartesian3.normalize(C.Cartesian3.negate(dir, dir), new C.Cartesian3()),
  });
  scene.globe.enableLighting = true;
  scene.globe.dynamicAtmosphereLighting = false;
  scene.globe.lightingFadeOutDistance = 0.0;
  scene.globe.lightingFadeInDistance = 1.0;

  function statistics() {
    let triangles = 0;
    const levels = [];
    for (const tile of scene.globe._surface._tilesToRender) {
      levels.push(tile.level);
      const mesh = tile.data && tile.data.renderedMesh;
      if (mesh) triangles += mesh.indexCountWithoutSkirts / 3;
    }
    return { frames: window.approxtree.frames, globe: { tiles: levels.length, triangles, levels } };
  }
  let loadedFrames = 0;
  scene.postRender.addEventListener(() => {
    window.approxtree.frames += 1;
    // Loaded, with tiles drawn (before its first request the globe counts as loaded).
    const drawn = scene.globe._surface._tilesToRender.length > 0;
    loadedFrames = scene.globe.tilesLoaded && drawn ? loadedFrames + 1 : 0;
    if (loadedFrames >= 5 && !window.approxtree.ready) {
      window.approxtree.stats = statistics();
      window.approxtree.ready = true;
    }
  });
  window.approxtree.statistics = statistics;
}

main().catch((e) => {
  window.approxtree.error = String(e && e.message ? e.message : e);
  console.error(e);
});
