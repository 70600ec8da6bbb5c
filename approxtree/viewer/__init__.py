"""Interactive viewer (core paper, section 7): a glfw window over the public Engine API.

Pure parts, usable and tested without a window: camera controllers (controllers.py), key
bindings and scripted presses (keys.py), camera scripts (script.py), the settings the keys
change (settings.py), the map tools (map_tools.py: scale bar, north arrow, readout, measure,
profile, bookmarks). The window (app.Viewer) is a composition of small parts, each with one
role (parts.py lists them); they need glfw, GL and imgui-bundle, and are imported on first
use.
"""

from approxtree.viewer.controllers import FlyController, OrbitController, cursor_ray, pick_terrain
from approxtree.viewer.keys import BINDINGS, KeyPress, parse_key_presses
from approxtree.viewer.script import Keyframe, ScriptFrame, load_script, script_frames
from approxtree.viewer.settings import ViewSettings


def __getattr__(name: str):
    # The window needs glfw and moderngl: load it on first use.
    if name == "Viewer":
        from approxtree.viewer import app

        return app.Viewer
    raise AttributeError(f"module 'approxtree.viewer' has no attribute {name!r}")


__all__ = [
    "BINDINGS",
    "FlyController",
    "KeyPress",
    "Keyframe",
    "OrbitController",
    "ScriptFrame",
    "ViewSettings",
    "Viewer",
    "cursor_ray",
    "load_script",
    "parse_key_presses",
    "pick_terrain",
    "script_frames",
]
