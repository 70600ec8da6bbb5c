"""Window: a glfw window with an OpenGL 3.3 core context (moderngl), its sizes and coordinates.

Three kinds of coordinates meet in a window:

- window: glfw's cursor positions, screen units, y down;
- pixel: framebuffer pixels, y up (GL);
- image: framebuffer pixels, column and row from the top-left corner (screenshots, scripts).

The window hands glfw's input events to one handler (``listen``, see input.py); it draws
nothing itself.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Protocol

import moderngl
import numpy as np

from approxtree.errors import ContextUnavailableError, InvalidParameterError
from approxtree.io.atomic import atomic_write

_INSTALL_HINT = (
    "The viewer needs a display: run it on a desktop, or under a virtual X server "
    "(Debian/Ubuntu: apt-get install -y xvfb; then xvfb-run -a approxtree view ...)."
)


#: Seconds between window title updates (the title shows the frame time).
TITLE_INTERVAL_S = 0.25


def _glfw() -> Any:
    try:
        import glfw
    except ImportError as exc:  # pragma: no cover - glfw is a dependency
        raise ContextUnavailableError(f"The glfw package is missing ({exc}).") from exc
    return glfw


class EventHandler(Protocol):
    """The glfw callbacks a window's handler receives (glfw's own signatures)."""

    def on_key(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None: ...

    def on_mouse_button(self, window: Any, button: int, action: int, mods: int) -> None: ...

    def on_cursor(self, window: Any, x: float, y: float) -> None: ...

    def on_scroll(self, window: Any, xoff: float, yoff: float) -> None: ...


class Window:
    """A glfw window of ``size`` (w, h) titled ``title``; ``visible`` False hides it (for
    benchmarks that only need the context). ``ctx`` is its moderngl context; ``glfw`` the
    glfw module (its constants: PRESS, RELEASE, MOUSE_BUTTON_LEFT)."""

    def __init__(self, size: tuple[int, int], title: str, visible: bool = True) -> None:
        glfw = self.glfw = _glfw()
        self.title = title
        # glfw key codes ↔ key names without the KEY_ prefix (keys.py names keys so).
        self._names = {getattr(glfw, n): n[4:] for n in dir(glfw) if n.startswith("KEY_")}
        self._codes = {v: k for k, v in self._names.items()}
        # OpenGL 3.3 core, forward compatible (macOS needs it).
        if not glfw.init():
            raise ContextUnavailableError(f"glfw could not initialise. {_INSTALL_HINT}")
        for hint, value in (
            (glfw.CONTEXT_VERSION_MAJOR, 3),
            (glfw.CONTEXT_VERSION_MINOR, 3),
            (glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE),
            (glfw.OPENGL_FORWARD_COMPAT, True),
            (glfw.VISIBLE, bool(visible)),
        ):
            glfw.window_hint(hint, value)
        self.handle = glfw.create_window(int(size[0]), int(size[1]), title, None, None)
        if not self.handle:
            glfw.terminate()
            raise ContextUnavailableError(
                f"glfw could not open an OpenGL 3.3 core window. {_INSTALL_HINT}"
            )
        glfw.make_context_current(self.handle)
        glfw.swap_interval(0)
        self.ctx = moderngl.create_context()
        # Sizes kept from glfw's resize events: each query is an X round trip (about 1 ms
        # under Xvfb, several a frame). The title is set a few times a second at most.
        self._fb_size = tuple(int(v) for v in glfw.get_framebuffer_size(self.handle))
        self._win_size = tuple(int(v) for v in glfw.get_window_size(self.handle))
        glfw.set_framebuffer_size_callback(self.handle, self._on_framebuffer_size)
        glfw.set_window_size_callback(self.handle, self._on_window_size)
        self._titled_at = -TITLE_INTERVAL_S

    # -- keys and events ------------------------------------------------------------------------

    def key_name(self, code: int) -> str | None:
        """The name of glfw key ``code`` ("W", "F1", "PAGE_UP"), None for an unknown one."""
        return self._names.get(code)

    def key_code(self, name: str) -> int:
        """The glfw key code of ``name`` (any case); InvalidParameterError when unknown."""
        code = self._codes.get(name.upper())
        if code is None:
            raise InvalidParameterError(f"Unknown key {name!r}; use glfw key names (W, F1, TAB).")
        return code

    def listen(self, handler: EventHandler) -> None:
        """Send glfw's key, mouse button, cursor and scroll events to ``handler``."""
        glfw, w = self.glfw, self.handle
        glfw.set_key_callback(w, handler.on_key)
        glfw.set_mouse_button_callback(w, handler.on_mouse_button)
        glfw.set_cursor_pos_callback(w, handler.on_cursor)
        glfw.set_scroll_callback(w, handler.on_scroll)

    def poll(self) -> None:
        self.glfw.poll_events()

    def idle(self, seconds: float) -> None:
        """Wait for events at most ``seconds`` (a minimised window draws nothing)."""
        self.glfw.wait_events_timeout(seconds)

    @property
    def closing(self) -> bool:
        return bool(self.glfw.window_should_close(self.handle))

    def request_close(self) -> None:
        self.glfw.set_window_should_close(self.handle, True)

    # -- sizes and coordinates ------------------------------------------------------------------

    def _on_framebuffer_size(self, window: Any, w: int, h: int) -> None:
        self._fb_size = (int(w), int(h))

    def _on_window_size(self, window: Any, w: int, h: int) -> None:
        self._win_size = (int(w), int(h))

    def framebuffer_size(self) -> tuple[int, int]:
        """The framebuffer's size in pixels (as of the last events polled)."""
        return self._fb_size  # type: ignore[return-value]

    def size(self) -> tuple[int, int]:
        """The window's size in screen units (imgui's coordinates; as of the last events)."""
        return self._win_size  # type: ignore[return-value]

    def cursor(self) -> tuple[float, float]:
        """The cursor, window coordinates."""
        x, y = self.glfw.get_cursor_pos(self.handle)
        return float(x), float(y)

    def to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Window coordinates (y down, screen units) → framebuffer pixels (y up)."""
        ww, wh = self.size()
        fw, fh = self.framebuffer_size()
        sx, sy = fw / max(ww, 1), fh / max(wh, 1)
        return x * sx, fh - y * sy

    def to_image(self, x: float, y: float) -> tuple[float, float]:
        """Window coordinates (y down) → image pixel (column, row from the top)."""
        px, py = self.to_pixel(x, y)
        return px, self.framebuffer_size()[1] - py

    def from_image(self, xy: Any) -> tuple[float, float]:
        """Image pixel (column, row from the top) → window coordinates."""
        fw, fh = self.framebuffer_size()
        ww, wh = self.size()
        return xy[0] * ww / max(fw, 1), xy[1] * wh / max(fh, 1)

    # -- frames ---------------------------------------------------------------------------------

    def show(self, title: str) -> None:
        """Title the window (at most every TITLE_INTERVAL_S) and swap the back buffer to the
        screen."""
        now = time.perf_counter()
        if now - self._titled_at >= TITLE_INTERVAL_S:
            self.glfw.set_window_title(self.handle, title)
            self._titled_at = now
        self.glfw.swap_buffers(self.handle)

    def save_png(self, path: str | Path) -> Path:
        """Write the back buffer to ``path`` as an RGB PNG (atomically)."""
        from PIL import Image

        w, h = self.framebuffer_size()
        raw = self.ctx.fbo.read(viewport=(0, 0, w, h), components=3, alignment=1)
        image = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3)[::-1]
        path = Path(path)
        with atomic_write(path) as f:
            Image.fromarray(np.ascontiguousarray(image), mode="RGB").save(f, format="PNG")
        return path

    def close(self) -> None:
        """Release the context, close the window and end glfw."""
        self.ctx.release()
        self.glfw.destroy_window(self.handle)
        self.glfw.terminate()
