"""Key bindings of the viewer: one table from key (with modifiers) to action, and the parser
of scripted key presses (``--keys "3:L,5:shift+PAGE_UP"``).

Keys are named as glfw names them without the ``KEY_`` prefix (``W``, ``F1``, ``PAGE_UP``,
``LEFT_BRACKET``); a lower-case letter means the same key. Held keys (WASD, Q/E, shift) are
read as state by the fly controller; every other binding fires on press.
"""

from __future__ import annotations

from dataclasses import dataclass

from approxtree.errors import InvalidParameterError

#: glfw modifier bits (GLFW_MOD_*), kept here so this module imports no window library.
MOD_SHIFT, MOD_CONTROL, MOD_ALT = 0x1, 0x2, 0x4
_MOD_NAMES = {"shift": MOD_SHIFT, "ctrl": MOD_CONTROL, "control": MOD_CONTROL, "alt": MOD_ALT}

#: (key, modifiers) → (action, help text). Order is the order of the help overlay.
BINDINGS: dict[tuple[str, int], tuple[str, str]] = {
    ("F1", 0): ("help", "help overlay on/off"),
    ("1", 0): ("alpha_down", "alpha threshold / 1.5 (finer)"),
    ("2", 0): ("alpha_up", "alpha threshold x 1.5 (coarser)"),
    ("3", 0): ("gamma_down", "gamma threshold / 1.5"),
    ("4", 0): ("gamma_up", "gamma threshold x 1.5"),
    ("L", 0): ("wireframe", "wireframe on/off"),
    ("K", 0): ("skirts", "skirts on/off"),
    ("PAGE_UP", 0): ("exaggerate_up", "vertical exaggeration x 1.25"),
    ("PAGE_DOWN", 0): ("exaggerate_down", "vertical exaggeration / 1.25"),
    ("T", 0): ("thematic", "thematic layer on/off"),
    ("TAB", 0): ("next_texture", "next texture folder (--textures)"),
    ("H", 0): ("shading", "lighting auto / on / off (auto: light untextured terrain only)"),
    ("LEFT", 0): ("sun_left", "sun azimuth - 15 degrees"),
    ("RIGHT", 0): ("sun_right", "sun azimuth + 15 degrees"),
    ("UP", 0): ("sun_up", "sun altitude + 5 degrees"),
    ("DOWN", 0): ("sun_down", "sun altitude - 5 degrees"),
    ("M", 0): ("measure", "measure tool: click two points (distance, elevation profile)"),
    ("B", 0): ("bookmark", "save the view as a bookmark"),
    ("G", 0): ("fly_to_next", "fly to the next bookmark"),
    ("U", 0): ("ui", "map interface (panels, legend, scale bar, north arrow) on/off"),
    ("C", 0): ("freeze", "freeze the frustum (see the cut from outside)"),
    ("P", 0): ("screenshot", "screenshot (PNG with a timestamped name)"),
    ("F", 0): ("fly", "fly mode on/off (WASD, Q/E, mouse, shift faster)"),
    ("R", 0): ("reset", "reset the view"),
    ("ESCAPE", 0): ("quit", "quit"),
}

#: Keys held down in fly mode: key → (forward, right, up) direction.
FLY_KEYS: dict[str, tuple[float, float, float]] = {
    "W": (1.0, 0.0, 0.0),
    "S": (-1.0, 0.0, 0.0),
    "D": (0.0, 1.0, 0.0),
    "A": (0.0, -1.0, 0.0),
    "E": (0.0, 0.0, 1.0),
    "Q": (0.0, 0.0, -1.0),
}

#: Mouse help lines (no key behind them).
MOUSE_HELP = (
    "left drag: orbit (fly mode: look)",
    "right/middle or shift+left drag: pan",
    "wheel: zoom to the point under the cursor",
)


def action_for(key: str, mods: int) -> str | None:
    """The action bound to ``key`` with ``mods`` (shift-only bindings win, then plain)."""
    mods &= MOD_SHIFT | MOD_CONTROL | MOD_ALT
    hit = BINDINGS.get((key, mods)) or BINDINGS.get((key, 0))
    return hit[0] if hit else None


def help_lines() -> list[str]:
    """The help overlay's lines."""
    lines = []
    for (key, mods), (_, text) in BINDINGS.items():
        prefix = "shift+" if mods & MOD_SHIFT else ""
        lines.append(f"{prefix}{key:<10} {text}")
    return lines + list(MOUSE_HELP)


@dataclass(frozen=True)
class KeyPress:
    """A scripted press: at frame ``frame`` (0-based), key name as glfw names it, modifiers."""

    frame: int
    key: str
    mods: int = 0


def parse_key(token: str) -> tuple[str, int]:
    """ "shift+w" → ("W", MOD_SHIFT). Raises InvalidParameterError for an unknown modifier."""
    parts = [p.strip() for p in token.split("+") if p.strip()]
    if not parts:
        raise InvalidParameterError(f"Empty key name in {token!r}.")
    mods = 0
    for name in parts[:-1]:
        bit = _MOD_NAMES.get(name.lower())
        if bit is None:
            raise InvalidParameterError(
                f"Unknown modifier {name!r} in {token!r}; use shift, ctrl or alt."
            )
        mods |= bit
    return parts[-1].upper(), mods


def parse_key_presses(text: str) -> list[KeyPress]:
    """Parse ``"L,3:T,5:shift+PAGE_UP"``: ``FRAME:KEY``; a bare KEY presses at the frame of
    the item's position (item i at frame i)."""
    presses = []
    for i, item in enumerate(t.strip() for t in text.split(",")):
        if not item:
            continue
        frame_text, sep, key_text = item.partition(":")
        if sep:
            try:
                frame = int(frame_text)
            except ValueError:
                raise InvalidParameterError(
                    f"Bad key press {item!r}: expected FRAME:KEY with FRAME a whole number."
                ) from None
        else:
            frame, key_text = i, frame_text
        if frame < 0:
            raise InvalidParameterError(f"Bad key press {item!r}: the frame must be >= 0.")
        key, mods = parse_key(key_text)
        presses.append(KeyPress(frame, key, mods))
    return presses
