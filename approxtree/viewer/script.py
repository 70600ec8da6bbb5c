"""Camera scripts: a JSON list of keyframes replayed frame by frame (``--script FILE``).

A keyframe is ``{"eye": [x, y, z], "target": [x, y, z], "frames": n, "keys": ["L"]}`` in world
coordinates. The first keyframe is held for ``frames`` frames (default 1); every later one is
reached after ``frames`` frames (default 30) of interpolation from the previous one (eye and
target linear, eased with smoothstep), its last frame exactly at the keyframe. ``keys``
(optional) are pressed before the first frame of that keyframe's segment. The screenshot of
a keyframe is taken at its last frame.
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


@dataclass(frozen=True)
class ScriptFrame:
    """One frame of a replay: world eye and target (3,), keys pressed before it, and the
    index of the keyframe it completes (None in between)."""

    eye: np.ndarray
    target: np.ndarray
    keys: tuple[str, ...] = ()
    keyframe: int | None = None


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
        unknown = set(item) - {"eye", "target", "frames", "keys"}
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
        keyframes.append(Keyframe(eye, target, frames, tuple(keys)))
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
        frames.append(ScriptFrame(first.eye, first.target, keys, 0 if last else None))
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
            frames.append(ScriptFrame(eye, target, b.keys if k == 0 else (), j if last else None))
    return frames
