"""Camera scripts: a JSON list of keyframes replayed frame by frame (``--script FILE``).

A keyframe is ``{"eye": [x, y, z], "target": [x, y, z], "frames": n, "keys": ["L"]}`` in world
coordinates. The first keyframe is held for ``frames`` frames (default 1); every later one is
reached after ``frames`` frames (default 30) of interpolation from the previous one (eye and
target linear, eased with smoothstep), its last frame exactly at the keyframe. ``keys``
(optional) are pressed before the first frame of that keyframe's segment. The screenshot of
a keyframe is taken at its last frame.

``actions`` (optional) drive the map tools on the segment's first frame, in order; each is an
object with one field (pixels are image pixels: column, row from the top-left corner):
``{"cursor": [x, y]}`` moves the cursor (readout), ``{"click": [x, y]}`` clicks with the
measure tool (two clicks: distance and profile), ``{"bookmark": "name"}`` saves the pose,
``{"fly_to": "name"}`` flies there (the flight, not the script, moves the camera until it
lands), ``{"ui": false}`` hides the map interface, ``{"shot": "name.png"}`` saves the window
with its interface (into --screenshots), ``{"sun": [azimuth, altitude]}``,
``{"exaggeration": k}``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.viewer.keys import parse_key


@dataclass(frozen=True)
class Keyframe:
    eye: np.ndarray
    target: np.ndarray
    frames: int
    keys: tuple[str, ...] = ()
    actions: tuple[tuple[str, object], ...] = ()


#: Map-tool actions of a keyframe and a check of their value.
ACTIONS = {
    "cursor": lambda v: _pixel(v),
    "click": lambda v: _pixel(v),
    "bookmark": lambda v: isinstance(v, str) and bool(v),
    "fly_to": lambda v: isinstance(v, str) and bool(v),
    "ui": lambda v: isinstance(v, bool),
    "shot": lambda v: isinstance(v, str) and v.endswith(".png") and "/" not in v,
    "sun": lambda v: _numbers(v, 2),
    "exaggeration": lambda v: _numbers([v], 1) and v > 0,
}


def _numbers(v: object, n: int) -> bool:
    return (
        isinstance(v, list)
        and len(v) == n
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        and all(np.isfinite(v))
    )


def _pixel(v: object) -> bool:
    return _numbers(v, 2)


def _actions(at: str, value: object) -> tuple[tuple[str, object], ...]:
    if not isinstance(value, list):
        raise InvalidParameterError(f"{at}: actions must be a list of objects, got {value!r}.")
    out = []
    for a in value:
        if not isinstance(a, dict) or len(a) != 1:
            raise InvalidParameterError(
                f"{at}: each action is an object with one field, got {a!r}."
            )
        ((name, v),) = a.items()
        if name not in ACTIONS:
            raise InvalidParameterError(
                f"{at}: unknown action {name!r}; use one of {', '.join(ACTIONS)}."
            )
        if not ACTIONS[name](v):
            raise InvalidParameterError(f"{at}: bad value for action {name!r}: {v!r}.")
        out.append((name, v))
    return tuple(out)


@dataclass(frozen=True)
class ScriptFrame:
    """One frame of a replay: world eye and target (3,), keys pressed before it, and the
    index of the keyframe it completes (None in between)."""

    eye: np.ndarray
    target: np.ndarray
    keys: tuple[str, ...] = ()
    keyframe: int | None = None
    actions: tuple[tuple[str, object], ...] = ()


def _vector(where: str, name: str, value: object) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InvalidParameterError(f"{where}: {name} must be three finite numbers, got {value!r}.")
    return v


def parse_script(data: object, where: str = "script") -> list[Keyframe]:
    """Validate a decoded JSON script (a non-empty list of keyframe objects)."""
    if not isinstance(data, list) or not data:
        raise InvalidParameterError(
            f"{where} must be a non-empty JSON list of keyframes "
            '{"eye": [x, y, z], "target": [x, y, z], "frames": n}.'
        )
    keyframes = []
    for i, item in enumerate(data):
        at = f"{where}, keyframe {i}"
        if not isinstance(item, dict):
            raise InvalidParameterError(f"{at} must be an object, got {item!r}.")
        unknown = set(item) - {"eye", "target", "frames", "keys", "actions"}
        if unknown:
            raise InvalidParameterError(f"{at} has unknown fields {sorted(unknown)}.")
        eye = _vector(at, "eye", item.get("eye"))
        target = _vector(at, "target", item.get("target"))
        if np.array_equal(eye, target):
            raise InvalidParameterError(f"{at}: eye and target must differ.")
        frames = item.get("frames", 1 if i == 0 else 30)
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise InvalidParameterError(
                f"{at}: frames must be a whole number >= 1, got {frames!r}."
            )
        keys = item.get("keys", [])
        if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
            raise InvalidParameterError(f"{at}: keys must be a list of key names, got {keys!r}.")
        for k in keys:
            parse_key(k)
        actions = _actions(at, item.get("actions", []))
        keyframes.append(Keyframe(eye, target, frames, tuple(keys), actions))
    return keyframes


def load_script(path: str | os.PathLike) -> list[Keyframe]:
    """Read and validate a script file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InvalidParameterError(f"Camera script {path} does not exist.") from None
    except json.JSONDecodeError as exc:
        raise InvalidParameterError(f"Camera script {path} is not valid JSON: {exc}") from exc
    return parse_script(data, str(path))


def script_frames(keyframes: list[Keyframe]) -> list[ScriptFrame]:
    """Every frame of the replay, in order (see the module docstring)."""
    frames: list[ScriptFrame] = []
    first = keyframes[0]
    for k in range(first.frames):
        last = k == first.frames - 1
        keys = first.keys if k == 0 else ()
        acts = first.actions if k == 0 else ()
        frames.append(ScriptFrame(first.eye, first.target, keys, 0 if last else None, acts))
    for j in range(1, len(keyframes)):
        a, b = keyframes[j - 1], keyframes[j]
        t = np.arange(1, b.frames + 1) / b.frames
        s = t * t * (3.0 - 2.0 * t)
        for k, w in enumerate(s):
            eye = a.eye + w * (b.eye - a.eye)
            target = a.target + w * (b.target - a.target)
            if np.array_equal(eye, target):
                target = b.target
            last = k == b.frames - 1
            frames.append(
                ScriptFrame(
                    eye,
                    target,
                    b.keys if k == 0 else (),
                    j if last else None,
                    b.actions if k == 0 else (),
                )
            )
    return frames
