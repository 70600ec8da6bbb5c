// Load a 3D Tiles tileset with 3DTilesRendererJS (three.js) and report what it drew:
// window.approxtree = {ready, error, statistics()} as examples/web/viewer.js does for CesiumJS.
import * as THREE from "three";
import { DRACOLoader } from "three/addons/loaders/DRACOLoader.js";
import { MeshoptDecoder } from "three/addons/libs/meshopt_decoder.module.js";
import { TilesRenderer } from "3d-tiles-renderer";
import { GLTFExtensionsPlugin, ImplicitTilingPlugin } from "3d-tiles-renderer/plugins";

window.approxtree = { ready: false, error: null, frames: 0 };
const params = new URLSearchParams(window.location.search);

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
  const width = window.innerWidth;
  const height = window.innerHeight;
  const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(width, height);
  renderer.setClearColor(new THREE.Color(params.get("bg") || "#000000"));
  document.body.appendChild(renderer.domElement);

  const scene = new THREE.Scene();
  const vfov = params.has("vfov") ? Number(params.get("vfov")) : 45;
  const camera = new THREE.PerspectiveCamera(vfov, width / height, 1, 1e8);
  const pos = numbers("pos", 3);
  const dir = numbers("dir", 3) || [0, 0, -1];
  const up = numbers("up", 3) || [0, 0, 1];
  camera.position.set(...pos);
  camera.up.set(...up);
  camera.lookAt(pos[0] + dir[0], pos[1] + dir[1], pos[2] + dir[2]);
  camera.updateMatrixWorld();

  // Light from high on the camera's left (35° above the view's horizon), so the relief shows.
  scene.add(new THREE.AmbientLight(0xffffff, 0.5));
  const light = new THREE.DirectionalLight(0xffffff, 2.0);
  const ahead = new THREE.Vector3(...pos).addScaledVector(new THREE.Vector3(...dir), 1000);
  const left = new THREE.Vector3(...up).cross(new THREE.Vector3(...dir)).normalize();
  const sky = new THREE.Vector3(...up).multiplyScalar(Math.tan((35 * Math.PI) / 180));
  light.position.copy(ahead).addScaledVector(left.add(sky).normalize(), 1e4);
  light.target.position.copy(ahead);
  scene.add(light, light.target);

  const tiles = new TilesRenderer(params.get("tileset"));
  // The Draco decoder is fetched before any tile, so no fetch is left running at the end.
  const draco = new DRACOLoader().setDecoderPath("/node_modules/three/examples/jsm/libs/draco/");
  draco.setDecoderConfig({ type: "js" });
  await draco.preload().decoderPending;
  tiles.registerPlugin(new GLTFExtensionsPlugin({ dracoLoader: draco, meshoptDecoder: MeshoptDecoder }));
  tiles.registerPlugin(new ImplicitTilingPlugin());
  if (params.has("sse")) tiles.errorTarget = Number(params.get("sse"));
  tiles.setCamera(camera);
  tiles.setResolutionFromRenderer(camera, renderer);
  scene.add(tiles.group);

  const seen = new Set();
  let loadedFrames = 0;
  let started = false;
  tiles.addEventListener("load-error", (e) => {
    window.approxtree.error = `load-error ${e.url}: ${e.error && e.error.message}`;
  });
  tiles.addEventListener("tiles-load-start", () => (started = true));
  tiles.addEventListener("load-model", (e) => seen.add(e.url));

  function statistics() {
    let triangles = 0;
    let meshes = 0;
    for (const tile of tiles.visibleTiles) {
      const model = tile.engineData && tile.engineData.scene;
      if (!model) continue;
      model.traverse((o) => {
        if (o.isMesh && o.geometry) {
          meshes += 1;
          const index = o.geometry.index;
          triangles += (index ? index.count : o.geometry.attributes.position.count) / 3;
        }
      });
    }
    return {
      frames: window.approxtree.frames,
      visible: tiles.visibleTiles.size,
      meshes,
      triangles,
      loaded: seen.size,
      failed: tiles.stats.failed,
      depths: [...tiles.visibleTiles].map((t) => t.internal && t.internal.depth),
    };
  }
  window.approxtree.statistics = statistics;

  function frame() {
    camera.updateMatrixWorld();
    tiles.update();
    renderer.render(scene, camera);
    window.approxtree.frames += 1;
    const idle = started && !tiles.isLoading && tiles.stats.queued + tiles.stats.downloading + tiles.stats.parsing === 0;
    loadedFrames = idle ? loadedFrames + 1 : 0;
    if (loadedFrames >= 5 && !window.approxtree.ready) {
      window.approxtree.stats = statistics();
      window.approxtree.ready = true;
    }
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);
}

main().catch((e) => {
  window.approxtree.error = String(e && e.message ? e.message : e);
});
