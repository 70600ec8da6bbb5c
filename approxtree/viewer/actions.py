"""ACTIONS: what each action named in keys.BINDINGS does, one function per name.

A key press (input.py) and the Map panel's buttons (map_ui.py) call ``ACTIONS[name](viewer)``
through ``Viewer.do``; keys.BINDINGS says which key fires which name, this table what the name
does. tests/test_viewer.py checks that the two name the same actions.
"""

from __future__ import annotations

from collections.abc import Callable

from approxtree.viewer.parts import ViewerParts
from approxtree.viewer.settings import LIGHTING_MODES

#: Threshold and exaggeration steps of one key press.
THRESHOLD_STEP, EXAGGERATION_STEP = 1.5, 1.25
#: Sun steps of one key press (degrees).
SUN_AZIMUTH_STEP, SUN_ALTITUDE_STEP = 15.0, 5.0

Action = Callable[[ViewerParts], None]


def _toggle(name: str) -> Action:
    """Flip the boolean setting ``name``."""

    def toggle(v: ViewerParts) -> None:
        setattr(v.settings, name, not getattr(v.settings, name))

    return toggle


def _times(name: str, factor: float) -> Action:
    """Multiply the threshold setting ``name`` by ``factor``."""

    def times(v: ViewerParts) -> None:
        setattr(v.settings, name, getattr(v.settings, name) * factor)

    return times


def _exaggerate(factor: float) -> Action:
    def exaggerate(v: ViewerParts) -> None:
        v.set_exaggeration(v.settings.exaggeration * factor)

    return exaggerate


def _turn_sun(degrees: float) -> Action:
    def turn(v: ViewerParts) -> None:
        v.settings.sun_azimuth = (v.settings.sun_azimuth + degrees) % 360.0

    return turn


def _raise_sun(degrees: float) -> Action:
    def lift(v: ViewerParts) -> None:
        v.settings.sun_altitude = min(90.0, max(1.0, v.settings.sun_altitude + degrees))

    return lift


def _skirts(v: ViewerParts) -> None:
    v.settings.skirts = not v.settings.skirts
    v.driver.set_skirts(v.settings.skirts)


def _thematic(v: ViewerParts) -> None:
    v.settings.thematic = not v.settings.thematic
    v.apply_textures()


def _next_texture(v: ViewerParts) -> None:
    s = v.settings
    if v.pyramids:
        s.texture_index = (s.texture_index + 1) % len(v.pyramids)
        s.thematic = True
    v.apply_textures()


def _shading(v: ViewerParts) -> None:
    s = v.settings
    s.lighting = LIGHTING_MODES[(LIGHTING_MODES.index(s.lighting) + 1) % len(LIGHTING_MODES)]
    v.messages.append(f"lighting {s.lighting}")


def _freeze(v: ViewerParts) -> None:
    """Freeze the cut seen now (or let it follow the camera again)."""
    v.settings.frozen = not v.settings.frozen
    v.driver.thaw()
    if v.settings.frozen:
        v.driver.freeze(v.nav.camera(), v.window.framebuffer_size())


#: Action name (keys.BINDINGS) → what it does to the viewer.
ACTIONS: dict[str, Action] = {
    "help": _toggle("help"),
    "alpha_down": _times("alpha", 1 / THRESHOLD_STEP),
    "alpha_up": _times("alpha", THRESHOLD_STEP),
    "gamma_down": _times("gamma", 1 / THRESHOLD_STEP),
    "gamma_up": _times("gamma", THRESHOLD_STEP),
    "wireframe": _toggle("wireframe"),
    "skirts": _skirts,
    "exaggerate_up": _exaggerate(EXAGGERATION_STEP),
    "exaggerate_down": _exaggerate(1 / EXAGGERATION_STEP),
    "thematic": _thematic,
    "next_texture": _next_texture,
    "shading": _shading,
    "sun_left": _turn_sun(-SUN_AZIMUTH_STEP),
    "sun_right": _turn_sun(SUN_AZIMUTH_STEP),
    "sun_up": _raise_sun(SUN_ALTITUDE_STEP),
    "sun_down": _raise_sun(-SUN_ALTITUDE_STEP),
    "measure": lambda v: v.map.toggle_measure(),
    "bookmark": lambda v: v.map.save_bookmark(),
    "fly_to_next": lambda v: v.map.fly_to_next(),
    "ui": _toggle("ui"),
    "freeze": _freeze,
    "screenshot": lambda v: v.request_screenshot(),
    "fly": lambda v: v.nav.toggle_fly(),
    "reset": lambda v: v.nav.reset(),
    "quit": lambda v: v.window.request_close(),
}
