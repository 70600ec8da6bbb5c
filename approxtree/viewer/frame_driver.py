"""FrameDriver: every call the viewer makes into the Engine, in one place.

The Engine is embedded in the window (``Engine(tree, context=ctx)``) and draws into the
framebuffer bound there. Its frames page (``wait=False``): the provider loads payloads in the
background and the traversal draws their nearest resident ancestors meanwhile, uploading at
most ``max_uploads`` meshes (``budget_ms``) per frame, spending at most ``frame_margin_ms``
over the recent median frame time; only the root is uploaded up front. What the camera is
about to see (its motion extrapolated, the siblings of what it sees) is loaded ahead at a
lower priority (render/prefetch.py).
A frozen frustum draws the cut seen from the frozen view (``Cut(frozen=...)``).

Live (``follow``): every frame first polls the store and the pyramids another process may
update (``approxtree update``; render/live.py: one stat each); the Engine then draws the new
tree and textures with the unchanged nodes' and tiles' payloads still cached.

The rest of the viewer reads and changes the Engine only through this class, so a change of
the Engine's API is made here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.camera import Camera
from approxtree.render.cut import Cut
from approxtree.render.engine import Engine, Frame
from approxtree.render.frame_state import FrameState
from approxtree.render.live import LiveChange, LiveFollower
from approxtree.render.style import Style, Sun
from approxtree.render.traversal import Paging
from approxtree.viewer.settings import ViewSettings


class FrameDriver:
    """The Engine over ``tree`` drawing into ``ctx``, with the viewer's frame options.

    settings: the shared ViewSettings (cut, wireframe, light); exaggeration, palette: the
    Engine's picture options; background: Engine.render's; max_uploads, budget_ms: the
    per-frame upload budget (0 and None: no budget, every frame waits for its whole cut);
    frame_margin_ms: the upload budget follows the frame time, this margin over its recent
    median (None: it does not).
    """

    def __init__(
        self,
        tree: Any,
        ctx: Any,
        settings: ViewSettings,
        exaggeration: float = 1.0,
        palette: str | None = None,
        background: str = "sky",
        max_uploads: int = 32,
        budget_ms: float | None = None,
        frame_margin_ms: float | None = 4.0,
    ) -> None:
        if max_uploads < 0:
            raise InvalidParameterError(f"max_uploads must be >= 0, got {max_uploads}")
        self.tree = tree
        self.ctx = ctx
        self.settings = settings
        self.background = background
        self.max_uploads = int(max_uploads)
        self.budget_ms = budget_ms
        self.frame_margin_ms = frame_margin_ms
        self.engine = Engine(tree, context=ctx, exaggeration=float(exaggeration), palette=palette)
        self._frozen: FrameState | None = None
        #: Follows a store and pyramids updated by another process (``follow``), or None.
        self.live: LiveFollower | None = None
        # The root's mesh now: it also loads the compiled skirt kernels before frame 0.
        self.engine.upload(0)

    # -- what the rest of the viewer reads ------------------------------------------------------

    @property
    def scale(self) -> np.ndarray:
        """(3,) display scale: world units → display units, exaggeration included."""
        return self.engine.scale

    @property
    def palette(self) -> Any:
        """The hypsometric palette of untextured terrain (textures/palettes.py)."""
        return self.engine.palette

    @property
    def colour_layer(self) -> bool:
        """True when the drawn texture layer carries colours, not baked shading."""
        return not self.engine.shade_texture

    # -- settings the Engine keeps --------------------------------------------------------------

    def set_textures(self, pyramid: Any) -> None:
        """Drape ``pyramid`` (a TexturePyramid or DetailTextures) over the terrain; None:
        untextured."""
        self.engine.set_textures(pyramid)

    def set_skirts(self, on: bool) -> None:
        self.engine.set_skirts(on)

    def set_exaggeration(self, factor: float) -> None:
        """Draw z times ``factor``; ``scale`` follows."""
        self.engine.set_vertical_exaggeration(factor)

    def follow(self, store: Any, pyramids: list[Any], loader: Any) -> None:
        """Follow the store folder ``store`` (or None) and the pyramid folders ``pyramids``
        as another process updates them; ``loader(path)`` loads the store's new tree."""
        self.live = LiveFollower(self.engine, store, pyramids, loader)

    def take_changes(self) -> list[LiveChange]:
        """What the frames followed since the last call (render/live.py), oldest first."""
        return self.live.take() if self.live is not None else []

    def freeze(self, camera: Camera, size: tuple[int, int]) -> None:
        """Keep drawing the cut seen by ``camera`` whatever the camera does next."""
        self._frozen = self.engine.frame_state(camera, size)

    def thaw(self) -> None:
        self._frozen = None

    # -- frames ---------------------------------------------------------------------------------

    def draw(
        self,
        camera: Camera,
        size: tuple[int, int],
        positions: bool = False,
        path: Sequence[Camera] = (),
    ) -> Frame:
        """Draw one interactive frame into the window's framebuffer; ``positions``: also
        read the drawn world positions (Frame.positions, an extra pass); ``path``: cameras
        the view will pass next (a fly-to), whose cuts are prefetched (``Paging.path``)."""
        s = self.settings
        self.ctx.fbo.use()
        # Live: poll the store and pyramids first (and again for a frame that met a swap).
        render = self.engine.render if self.live is None else self.live.render
        frame = render(
            camera,
            size,
            # While frozen, the cut of the frozen frustum.
            Cut(s.alpha, s.gamma, frozen=self._frozen),
            style=Style(
                s.lighting, Sun(s.sun_azimuth, s.sun_altitude), self.background, s.wireframe
            ),
            # Without an upload budget every wanted mesh loads in the frame that wants it.
            paging=Paging(
                wait=not self.max_uploads and self.budget_ms is None,
                max_uploads=self.max_uploads or None,
                upload_ms=self.budget_ms,
                frame_margin_ms=self.frame_margin_ms,
                path=tuple(path),
            ),
        )
        if positions:
            self.engine.world_positions(frame)
        # The positions pass binds its own framebuffer: the window's again for the interface.
        self.ctx.fbo.use()
        return frame

    def settle(self) -> None:
        """Wait until the payloads this frame requested are loaded and the texture patches'
        mip chains made (scripted replays)."""
        if self.engine.provider is not None:
            self.engine.provider.wait()
        self.engine.renderer.wait_textures()
        if self.live is not None:
            self.live.settle()

    def release(self) -> None:
        self.engine.release()
