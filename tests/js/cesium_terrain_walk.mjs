// Loads a quantized-mesh folder with CesiumJS's own CesiumTerrainProvider (Node, no browser):
// layer.json parsing, every tile decoded (gzip over HTTP, header, extensions), availability
// from the tiles' metadata. Walks the quadtree as CesiumJS does (a child is requested when
// getTileDataAvailable does not say false) and prints one JSON line of what it loaded.
//     node cesium_terrain_walk.mjs ENGINE_INDEX_JS TILESET_DIR
import fs from "node:fs";
import http from "node:http";
import path from "node:path";
import { pathToFileURL } from "node:url";

const [engine, root] = process.argv.slice(2);
const { CesiumTerrainProvider } = await import(pathToFileURL(engine).href);
const server = http.createServer((req, res) => {
  const p = path.join(root, decodeURIComponent(req.url.split("?")[0]));
  if (!fs.existsSync(p) || fs.statSync(p).isDirectory()) {
    res.writeHead(404);
    res.end();
    return;
  }
  const headers = p.endsWith(".terrain")
    ? { "Content-Type": "application/vnd.quantized-mesh", "Content-Encoding": "gzip" }
    : { "Content-Type": "application/json" };
  res.writeHead(200, headers);
  res.end(fs.readFileSync(p));
});
await new Promise((resolve) => server.listen(0, "127.0.0.1", resolve));
const url = `http://127.0.0.1:${server.address().port}/`;
const provider = await CesiumTerrainProvider.fromUrl(url, {
  requestVertexNormals: true,
  requestWaterMask: true,
});
const tiles = [];
let frontier = [[0, 0, 0], [1, 0, 0]];
while (frontier.length) {
  const next = [];
  for (const [x, y, level] of frontier) {
    if (provider.getTileDataAvailable(x, y, level) === false) continue;
    const data = await provider.requestTileGeometry(x, y, level);
    if (!data) throw new Error(`no data for ${level}/${x}/${y}`);
    // CesiumJS counts y from the north; report the TMS y of the file.
    tiles.push({
      level,
      x,
      y: (1 << level) - 1 - y,
      vertices: data._quantizedVertices.length / 3,
      normals: data._encodedNormals ? data._encodedNormals.length / 2 : 0,
      waterMask: data._waterMask ? data._waterMask.length : 0,
      minimumHeight: data._minimumHeight,
      maximumHeight: data._maximumHeight,
    });
    for (const [dx, dy] of [[0, 0], [1, 0], [0, 1], [1, 1]]) {
      next.push([2 * x + dx, 2 * y + dy, level + 1]);
    }
  }
  frontier = next;
}
server.close();
console.log(
  JSON.stringify({
    hasVertexNormals: provider.hasVertexNormals,
    hasWaterMask: provider.hasWaterMask,
    hasMetadata: provider.hasMetadata,
    tiles,
  }),
);
