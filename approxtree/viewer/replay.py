"""Replay: what a scripted run adds to the frame loop, and the stats line of every frame.

A run may replay a camera script (script.py: one ScriptFrame per frame, with keys and map-tool
actions) and scripted key presses (``--keys``). Scripted runs step time by SCRIPT_DT, so
replays move the same on any machine. The frame loop (app.Viewer.run) asks the Replay for
each frame's presses and script frame, carries out its actions (SCRIPT_ACTIONS), and hands
it one stats line per frame, written as JSON lines at the end (``--stats``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from approxtree.io.atomic import atomic_write
from approxtree.viewer.keys import KeyPress, parse_key
from approxtree.viewer.parts import ViewerParts
from approxtree.viewer.script import ScriptFrame

#: Time step of scripted frames (seconds), so replays move the same on any machine.
SCRIPT_DT = 1.0 / 30.0
#: Longest time step of an interactive frame (seconds): a stall does not fling the camera.
MAX_DT = 0.25


class Replay:
    """The scripted side of one run.

    script: frames of a camera replay (None: none); key_presses: scripted presses by frame;
    stats_path: where the stats lines go (None: not kept); screenshots: folder
    of one PNG per completed keyframe (``keyframe_000.png`` ...) and of the script's shots;
    screenshot_dir: the shots' folder without ``screenshots``.
    """

    def __init__(
        self,
        script: Sequence[ScriptFrame] | None = None,
        key_presses: Sequence[KeyPress] = (),
        stats_path: str | Path | None = None,
        screenshots: str | Path | None = None,
        screenshot_dir: Path = Path("."),
    ) -> None:
        self.script = script
        self.by_frame: dict[int, list[KeyPress]] = {}
        for p in key_presses:
            self.by_frame.setdefault(p.frame, []).append(p)
        self.stats_path = stats_path
        self.shots = Path(screenshots) if screenshots is not None else None
        if self.shots is not None:
            self.shots.mkdir(parents=True, exist_ok=True)
        self.screenshot_dir = screenshot_dir
        self.scripted = script is not None or bool(self.by_frame)
        #: Screenshots (with the interface) to take once this frame's interface is drawn.
        self.ui_shots: list[Path] = []
        self.lines: list[bytes] = []

    def ended(self, frame: int) -> bool:
        """True once every frame of the script was drawn."""
        return self.script is not None and frame >= len(self.script)

    def step(self, frame: int) -> ScriptFrame | None:
        """The script's frame ``frame`` (None without a script)."""
        return self.script[frame] if self.script is not None else None

    def presses(self, frame: int) -> list[tuple[str, int]]:
        """(key, modifiers) pressed before frame ``frame``: --keys, then the script's keys."""
        pressed = [(p.key, p.mods) for p in self.by_frame.get(frame, [])]
        step = self.step(frame)
        if step is not None:
            pressed += [parse_key(k) for k in step.keys]
        return pressed

    def dt(self, now: float, last: float) -> float:
        """The time step of a frame starting at ``now`` after one that started at ``last``."""
        return SCRIPT_DT if self.scripted else min(now - last, MAX_DT)

    def act(self, viewer: ViewerParts, step: ScriptFrame) -> None:
        """Carry out the map-tool actions of script frame ``step`` (see script.py)."""
        for name, value in step.actions:
            SCRIPT_ACTIONS[name](self, viewer, value)

    def keyframe_shot(self, step: ScriptFrame | None) -> Path | None:
        """Where the screenshot of a completed keyframe goes (None: no screenshot)."""
        if step is None or step.keyframe is None or self.shots is None:
            return None
        return self.shots / f"keyframe_{step.keyframe:03d}.png"

    def take_ui_shots(self) -> list[Path]:
        """The interface screenshots asked for this frame (and forget them)."""
        shots, self.ui_shots = self.ui_shots, []
        return shots

    def record(self, stats: dict[str, Any]) -> None:
        """Keep one frame's stats line (as JSON) when a stats file was asked."""
        if self.stats_path is not None:
            self.lines.append((json.dumps(json_safe(stats)) + "\n").encode())

    def write(self) -> None:
        """Write the stats lines (atomically) when a stats file was asked."""
        if self.stats_path is not None:
            with atomic_write(self.stats_path) as f:
                f.writelines(self.lines)


def _shot(replay: Replay, v: ViewerParts, name: Any) -> None:
    folder = replay.shots if replay.shots is not None else replay.screenshot_dir
    replay.ui_shots.append(folder / name)


def _fly_to(replay: Replay, v: ViewerParts, name: Any) -> None:
    # The flight's first pose is this frame's; the flight owns the camera until it lands.
    v.map.fly_to(name)
    v.map.fly_on()


def _sun(replay: Replay, v: ViewerParts, value: Any) -> None:
    v.settings.sun_azimuth, v.settings.sun_altitude = map(float, value)


def _ui(replay: Replay, v: ViewerParts, value: Any) -> None:
    v.settings.ui = bool(value)


#: Script action (script.ACTIONS) → what it does; pixels are image pixels from the top-left.
SCRIPT_ACTIONS: dict[str, Callable[[Replay, ViewerParts, Any], None]] = {
    "cursor": lambda r, v, xy: v.input.move_cursor(*v.window.from_image(xy)),
    "click": lambda r, v, xy: v.input.click(*v.window.from_image(xy)),
    "bookmark": lambda r, v, name: v.map.save_bookmark(name),
    "fly_to": _fly_to,
    "ui": _ui,
    "shot": _shot,
    "sun": _sun,
    "exaggeration": lambda r, v, k: v.set_exaggeration(float(k)),
}


def stats_line(
    stats: dict[str, Any],
    frame: int,
    frame_ms: float,
    size: tuple[int, int],
    step: ScriptFrame | None,
    viewer: ViewerParts,
    ui_boxes: dict[str, Any],
) -> dict[str, Any]:
    """One frame's stats line: the Engine's frame stats, then the frame's number, time and
    size, its keyframe (scripted runs), the settings, the pose (world), the map tools and the
    interface's boxes (None while it is hidden)."""
    s = viewer.settings
    line = dict(stats)
    line.update(frame=frame, frame_ms=round(frame_ms, 3), size=list(size))
    if step is not None:
        line["keyframe"] = step.keyframe
    eye, target = viewer.nav.pose_world()
    figures = viewer.map.figures()
    line.update(
        alpha=s.alpha,
        gamma=s.gamma,
        eye=eye.tolist(),
        target=target.tolist(),
        mode="fly" if s.fly else "orbit",
        frozen=s.frozen,
        sun=[s.sun_azimuth, s.sun_altitude],
        exaggeration=s.exaggeration,
        lighting=s.lighting,
        cursor=figures["cursor"],
        measure=figures["measure"],
        ui=ui_boxes if s.ui else None,
        flying=viewer.map.flying,
    )
    return line


def frame_title(title: str, stats: dict[str, Any], frame_ms: float) -> str:
    """The window title of a frame: its time, triangles, patches, texture switches, α, γ."""
    return (
        f"{title} — {frame_ms:.1f} ms, {stats['triangles']:,} triangles, "
        f"{stats['patches']} patches, {stats['texture_switches']} texture switches, "
        f"max α {stats['max_alpha']:.2f} px, max γ {stats['max_gamma']:.2f} px²"
    )


def json_safe(stats: dict[str, Any]) -> dict[str, Any]:
    """JSON has no inf or NaN: report them as null."""
    return {
        k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in stats.items()
    }
