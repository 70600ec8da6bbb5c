"""What the gallery's examples share: where the real data are, a work folder, and figures.

Not an example itself (sphinx-gallery runs only the ``plot_*.py`` files). The real data live
in ``../shared/data`` beside the project root, or wherever ``APPROXTREE_DATA`` points; an
example whose file is absent prints why and shows a placeholder instead of its picture.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("APPROXTREE_DATA", ROOT.parent / "shared" / "data"))
#: Outputs of the examples (trees, pyramids, tiles): one temporary folder per run.
WORK = Path(tempfile.mkdtemp(prefix="approxtree_gallery_"))
atexit.register(shutil.rmtree, WORK, True)


def data_file(relative: str) -> Path | None:
    """The real data file ``relative`` (e.g. "nc/elev_ned_30m.tif"), or None, saying so."""
    path = DATA / relative
    if path.exists():
        return path
    print(f"Real data file {path} is absent: set APPROXTREE_DATA to the folder of shared/data.")
    return None


def show(images: list[np.ndarray], titles: list[str], width: float = 9.0) -> None:
    """Show (h, w, 3|4) uint8 images side by side, one title each, without axes."""
    h, w = images[0].shape[:2]
    fig, axes = plt.subplots(
        1, len(images), figsize=(width, width * h / (w * len(images)) + 0.5), squeeze=False
    )
    for ax, image, title in zip(axes[0], images, titles, strict=True):
        ax.imshow(image)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    fig.tight_layout()


def placeholder(message: str) -> None:
    """A figure that says why there is no picture (data or a tool absent on this machine)."""
    _, ax = plt.subplots(figsize=(6, 1.5))
    ax.text(0.5, 0.5, message, ha="center", va="center", wrap=True, fontsize=10)
    ax.set_axis_off()
