"""MultiTexture: layers blended into one texture (multiply, overlay, soft light, alpha over,
shade).

Formulas are the W3C compositing ones, on colours in [0, 1]; a layer only acts where its alpha
is non-zero, weighted by that alpha. All layers must share the first layer's lattice.

"shade" is the relief-map blend of a thematic layer with a hillshade: flat ground (the shade
of a 45° sun, 0.707) keeps the legend colour, lit slopes lighten it a little and shadowed ones
darken it (colour × (0.3 + 0.7 · shade / 0.707), at most × 1.25). Plain multiply darkens
every colour by the flat-ground shade and lets saturated legends drown the relief.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.textures.base import TextureData


def _soft_light(b: np.ndarray, s: np.ndarray) -> np.ndarray:
    d = np.where(b <= 0.25, ((16 * b - 12) * b + 4) * b, np.sqrt(b))
    return np.where(s <= 0.5, b - (1 - 2 * s) * b * (1 - b), b + (2 * s - 1) * (d - b))


#: Shade of flat ground under a 45° sun (sin 45°): "shade" keeps the backdrop there.
FLAT_SHADE = 0.7071


def _shade(b: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.clip(b * np.clip(0.3 + 0.7 * s / FLAT_SHADE, 0.0, 1.25), 0.0, 1.0)


#: Texels blended at a time by ``MultiTexture.band_strips``.
BLEND_TEXELS = 2**18


#: Blend mode → function (backdrop, source) of colours in [0, 1].
BLEND_MODES = {
    "shade": _shade,
    "multiply": lambda b, s: b * s,
    "overlay": lambda b, s: np.where(b <= 0.5, 2 * b * s, 1 - 2 * (1 - b) * (1 - s)),
    "soft-light": _soft_light,
    "over": lambda b, s: s,
}


def blend(backdrop: np.ndarray, source: np.ndarray, mode: str) -> np.ndarray:
    """Blend RGBA ``source`` onto RGBA ``backdrop``: both (rows, cols, 4) uint8."""
    if mode not in BLEND_MODES:
        raise InvalidParameterError(
            f"Unknown blend mode {mode!r}; choose one of {list(BLEND_MODES)}."
        )
    b = backdrop[..., :3] / 255.0
    s = source[..., :3] / 255.0
    ab = backdrop[..., 3:] / 255.0
    a_s = source[..., 3:] / 255.0
    mixed = BLEND_MODES[mode](b, s)
    # Source alpha decides how much of the blended colour replaces the backdrop; where the
    # backdrop is empty the source shows as it is.
    colour = np.where(ab > 0, b * (1 - a_s) + mixed * a_s, s)
    alpha = a_s + ab * (1 - a_s)
    out = np.concatenate([colour, alpha], axis=-1)
    return np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)


class MultiTexture(TextureData):
    """Two or more textures on one lattice, blended in order: layer 0 is the backdrop.

    layers: the textures; modes: one blend mode per layer after the first.
    """

    def __init__(self, layers: Sequence[TextureData], modes: Sequence[str]) -> None:
        if len(layers) < 2:
            raise InvalidParameterError("MultiTexture needs at least two layers.")
        if len(modes) != len(layers) - 1:
            raise InvalidParameterError(
                f"Give one blend mode per layer after the first: {len(layers) - 1} modes for "
                f"{len(layers)} layers, got {len(modes)}."
            )
        base = layers[0]
        for layer in layers[1:]:
            if layer.shape != base.shape or not layer.transform.almost_equals(base.transform):
                raise InvalidParameterError(
                    "All layers of a MultiTexture must share one lattice (shape and transform); "
                    "resample them to the first layer first."
                )
        for m in modes:
            if m not in BLEND_MODES:
                raise InvalidParameterError(
                    f"Unknown blend mode {m!r}; choose one of {list(BLEND_MODES)}."
                )
        self.layers = list(layers)
        self.modes = list(modes)
        self.transform = base.transform
        self.shape = base.shape
        self.crs = base.crs

    def rgba(self) -> np.ndarray:
        out = self.layers[0].rgba()
        for layer, mode in zip(self.layers[1:], self.modes, strict=True):
            out = blend(out, layer.rgba(), mode)
        return out

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        """(4, ≤ rows, cols) uint8 strips, each the blend of the layers' strips: layers that
        stream (an image, a shading's grey levels) are never whole in memory as RGBA."""
        streams = [layer.band_strips(rows) for layer in self.layers]
        # Each layer's strip is valid until its next is asked for: blended before that, a few
        # rows at a time (the float64 temporaries of a blend are ~100 bytes a texel).
        for strips in zip(*streams, strict=True):
            n, cols = strips[0].shape[1:]
            out = np.empty((4, n, cols), dtype=np.uint8)
            step = max(1, BLEND_TEXELS // max(cols, 1))
            for r0 in range(0, n, step):
                rgba = np.moveaxis(strips[0][:, r0 : r0 + step], 0, -1)
                for strip, mode in zip(strips[1:], self.modes, strict=True):
                    rgba = blend(rgba, np.moveaxis(strip[:, r0 : r0 + step], 0, -1), mode)
                out[:, r0 : r0 + step] = np.moveaxis(rgba, -1, 0)
            yield out
