"""Build the approximation tree of a terrain file (or the sample DEM) and walk its top levels.

    python examples/build_tree.py [DEM] [--epsilon 1.0]

Shows the public API: open_terrain, ApproximationTree.build, nodes, patches, save and load.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import approxtree as at
from approxtree.datasets import sample_terrain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dem", nargs="?", help="terrain file (default: matplotlib's sample DEM)")
    parser.add_argument("--epsilon", type=float, default=1.0, help="threshold ε in z units")
    args = parser.parse_args()

    terrain = at.open_terrain(args.dem) if args.dem else sample_terrain()
    print(terrain)
    tree = at.ApproximationTree.build(terrain, epsilon=args.epsilon, max_points=33 * 33)
    print(tree.stats())

    # The first two levels: each node's domain, exact error and patch size.
    for node in [tree.root, *tree.root.children]:
        patch = node.patch
        print(
            f"level {node.level} {node.strategy:>4}  error {node.error:8.3f}  "
            f"{patch.point_count:5d} points  {len(patch.triangles):5d} triangles  {node.rect}"
        )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "terrain.zarr.zip"
        size = tree.save(path)
        again = at.ApproximationTree.load(path)
        print(f"saved {size} bytes; reloaded {len(again)} nodes, root error {again.root.error:g}")


if __name__ == "__main__":
    main()
