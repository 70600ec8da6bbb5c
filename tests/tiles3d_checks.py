"""Readers and checkers of 3D Tiles output shared by the tiles tests: GLB arrays, the tile walk
with cumulative transforms, the Khronos glTF validator, and the subset of the 3D Tiles 1.1
JSON schema that tileset.json must meet (the npm registry has no CesiumGS 3D Tiles validator:
``3d-tiles-validator`` and ``@cesium/3d-tiles-validator`` are not published, and
``3d-tiles-tools`` ships no schema, so the required parts of the official schema —
tileset, asset, tile, boundingVolume, content — are written out here)."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
VALIDATE_GLTF = ROOT / "web" / "validate_gltf.mjs"

_NUMBER = {"type": "number"}

#: Required subset of the 3D Tiles 1.1 schema (tileset, asset, tile, boundingVolume, content).
TILESET_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object",
    "required": ["asset", "geometricError", "root"],
    "properties": {
        "asset": {
            "type": "object",
            "required": ["version"],
            "properties": {"version": {"type": "string"}, "tilesetVersion": {"type": "string"}},
        },
        "geometricError": {"type": "number", "minimum": 0},
        "root": {"$ref": "#/$defs/tile"},
    },
    "$defs": {
        "tile": {
            "type": "object",
            "required": ["boundingVolume", "geometricError"],
            "properties": {
                "boundingVolume": {"$ref": "#/$defs/boundingVolume"},
                "viewerRequestVolume": {"$ref": "#/$defs/boundingVolume"},
                "geometricError": {"type": "number", "minimum": 0},
                "refine": {"enum": ["ADD", "REPLACE"]},
                "transform": {"type": "array", "items": _NUMBER, "minItems": 16, "maxItems": 16},
                "content": {
                    "type": "object",
                    "required": ["uri"],
                    "properties": {
                        "uri": {"type": "string"},
                        "boundingVolume": {"$ref": "#/$defs/boundingVolume"},
                    },
                },
                "children": {"type": "array", "items": {"$ref": "#/$defs/tile"}, "minItems": 1},
            },
        },
        "boundingVolume": {
            "type": "object",
            "minProperties": 1,
            "properties": {
                "box": {"type": "array", "items": _NUMBER, "minItems": 12, "maxItems": 12},
                "region": {"type": "array", "items": _NUMBER, "minItems": 6, "maxItems": 6},
                "sphere": {"type": "array", "items": _NUMBER, "minItems": 4, "maxItems": 4},
            },
        },
    },
}


def check_schema(tileset: dict) -> None:
    """Validate tileset.json against TILESET_SCHEMA plus the semantic rules of the spec the
    schema cannot state (region ranges, a root transform that is invertible)."""
    jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is not installed")
    jsonschema.validate(tileset, TILESET_SCHEMA)
    assert tileset["asset"]["version"] == "1.1"
    for tile, _, _ in walk(tileset):
        region = tile["boundingVolume"].get("region")
        if region is not None:
            w, s, e, n, lo, hi = region
            assert -np.pi <= w <= e <= np.pi and -np.pi / 2 <= s <= n <= np.pi / 2
            assert lo <= hi
        m = np.array(tile["transform"]).reshape(4, 4).T
        assert abs(np.linalg.det(m)) > 0 and np.allclose(m[3], (0, 0, 0, 1))


def walk(tileset: dict) -> Iterator[tuple[dict, dict | None, np.ndarray]]:
    """(tile, parent tile or None, cumulative (4, 4) transform) for every tile, parents first."""
    stack: list[tuple[dict, dict | None, np.ndarray]] = [(tileset["root"], None, np.eye(4))]
    while stack:
        tile, parent, above = stack.pop()
        m = above @ np.array(tile.get("transform", np.eye(4).ravel())).reshape(4, 4).T
        yield tile, parent, m
        stack.extend((child, tile, m) for child in tile.get("children", []))


#: glTF index component types.
_INDEX = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}


def read_glb(path: Path) -> dict[str, Any]:
    """The arrays of a GLB written by approxtree.io.gltf: positions, normals, uvs (or None),
    triangles (m, 3), image bytes (or None), the root node's matrix, scene extras."""
    import pygltflib as g

    gltf = g.GLTF2().load_binary(str(path))
    blob = gltf.binary_blob()

    def view(k: int) -> bytes:
        v = gltf.bufferViews[k]
        return blob[v.byteOffset : v.byteOffset + v.byteLength]

    def accessor(k: int, dtype: Any, width: int) -> np.ndarray:
        a = gltf.accessors[k]
        return np.frombuffer(view(a.bufferView), dtype=dtype).reshape(-1, width)

    prim = gltf.meshes[0].primitives[0]
    uv = prim.attributes.TEXCOORD_0
    return {
        "positions": accessor(prim.attributes.POSITION, np.float32, 3),
        "normals": accessor(prim.attributes.NORMAL, np.float32, 3),
        "uvs": None if uv is None else accessor(uv, np.float32, 2),
        "triangles": accessor(prim.indices, _INDEX[gltf.accessors[prim.indices].componentType], 3),
        "image": view(gltf.images[0].bufferView) if gltf.images else None,
        "matrix": gltf.nodes[0].matrix,
        "extras": gltf.scenes[0].extras,
    }


def gltf_validator() -> list[str]:
    """The command running the Khronos glTF validator, or a skip saying what is missing."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (the glTF validator runs on Node.js)")
    if not (ROOT / "web" / "node_modules" / "gltf-validator").is_dir():
        pytest.skip("npm package gltf-validator missing: run `npm ci --prefix web`")
    return [node, str(VALIDATE_GLTF)]


def validate_gltf(paths: list[Path]) -> list[dict]:
    """Khronos glTF validator reports of ``paths`` (batched): file, errors, warnings, messages."""
    command = gltf_validator()
    reports: list[dict] = []
    for k in range(0, len(paths), 200):
        batch = [str(p) for p in paths[k : k + 200]]
        done = subprocess.run(command + batch, capture_output=True, text=True, check=True)
        reports.extend(json.loads(done.stdout))
    return reports
