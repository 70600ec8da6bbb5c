"""EngineFeatures: what the Engine at hand offers, found by feature detection.

The viewer uses the public Engine API only. Texture pyramids (``Engine.set_textures``) and
unlit drawing (``render(..., lighting=False)``) arrive with the textured renderer; on an
Engine without them the thematic and shading toggles are kept as state, reported as
unavailable, and change nothing, so the viewer runs on either.
"""

from __future__ import annotations

import inspect
from typing import Any


class EngineFeatures:
    """Adapter over one Engine: ``textures`` and ``lighting`` say what it supports."""

    def __init__(self, engine: Any) -> None:
        self.engine = engine
        self.textures = callable(getattr(engine, "set_textures", None))
        params = inspect.signature(engine.render).parameters
        # Lighting is a render option, or part of the frame's Style.
        self.lighting = "lighting" in params or "style" in params

    def set_textures(self, pyramid: Any) -> bool:
        """Give the Engine ``pyramid`` (or None); False when the Engine cannot texture."""
        if not self.textures:
            return False
        self.engine.set_textures(pyramid)
        return True

    def render_options(self, lighting: bool | str) -> dict[str, Any]:
        """Keyword arguments of ``render`` for the optional features."""
        return {"lighting": lighting} if self.lighting else {}
