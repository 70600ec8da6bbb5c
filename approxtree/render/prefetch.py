"""Prefetch: where the camera goes next, and how much a frame may spend on uploads (no GL).

Two small stateful helpers of an interactive frame (``Paging(wait=False)``, traversal.py), kept
by the tile source from frame to frame:

- ``MotionPredictor`` remembers the eye and viewing direction of the last frames and
  extrapolates them ``frames`` ahead (constant velocity and turn rate, in display units): the
  cut of that predicted view is requested after the current frame's, so what the camera is
  about to see is loaded before it is seen. A jump much larger than the recent motion (a
  camera cut, a teleport) or a sharp turn forgets the history: no prediction from a cut.
- ``FrameBudget`` lets the upload budget follow the frame time: the frame's target is the
  recent median of its time without mesh uploads plus a margin, and the uploads may spend
  what the last frame's other work leaves of it, never less than the margin (and at least
  one upload a frame: the renderer counts its budget after the first).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.camera import Camera
from approxtree.render.frame_state import FrameState

#: A step larger than this many times the median of the recent steps is a camera cut.
CUT_FACTOR = 8.0
#: A turn sharper than this (degrees in one frame) is a camera cut.
CUT_DEGREES = 30.0


class MotionPredictor:
    """Eye and viewing direction of the last ``history`` frames (display units), and the
    camera they extrapolate to (see the module docstring)."""

    def __init__(self, history: int = 4) -> None:
        if history < 2:
            raise InvalidParameterError(f"history must be >= 2 frames, got {history}.")
        self.eyes: deque[np.ndarray] = deque(maxlen=history)
        self.forwards: deque[np.ndarray] = deque(maxlen=history)
        #: Camera cuts seen (history forgotten).
        self.cuts = 0

    def observe(self, fs: FrameState) -> None:
        """Record the view of ``fs``; a cut (see CUT_FACTOR, CUT_DEGREES) forgets the past."""
        eye = (np.asarray(fs.eye, dtype=np.float64) - fs.origin) * fs.scale
        # Row 2 of the view's rotation points backwards (GL look-at).
        forward = -np.asarray(fs.view[2, :3], dtype=np.float64)
        forward = forward / max(float(np.linalg.norm(forward)), 1e-300)
        if self.eyes and self._is_cut(eye, forward):
            self.eyes.clear()
            self.forwards.clear()
            self.cuts += 1
        self.eyes.append(eye)
        self.forwards.append(forward)

    def _is_cut(self, eye: np.ndarray, forward: np.ndarray) -> bool:
        """Whether the step to (eye, forward) jumps far beyond the recent motion."""
        step = float(np.linalg.norm(eye - self.eyes[-1]))
        turn = math.degrees(math.acos(float(np.clip(forward @ self.forwards[-1], -1.0, 1.0))))
        if turn > CUT_DEGREES:
            return True
        if len(self.eyes) < 2:
            return False
        steps = np.linalg.norm(np.diff(np.asarray(self.eyes), axis=0), axis=1)
        return step > CUT_FACTOR * float(np.median(steps)) and step > 0.0

    def predict(self, fs: FrameState, frames: float) -> Camera | None:
        """The camera ``frames`` frames after the last observed one (``fs``: that frame, for
        its origin, scale and fov), or None without motion history or motion."""
        if len(self.eyes) < 2 or frames <= 0:
            return None
        eyes, forwards = np.asarray(self.eyes), np.asarray(self.forwards)
        n = len(eyes) - 1
        velocity = (eyes[-1] - eyes[0]) / n
        turn = (forwards[-1] - forwards[0]) / n
        if not (velocity.any() or turn.any()):
            return None
        eye = eyes[-1] + frames * velocity
        forward = forwards[-1] + frames * turn
        norm = float(np.linalg.norm(forward))
        forward = forwards[-1] if norm < 1e-9 else forward / norm
        eye_w = eye / fs.scale + fs.origin
        target_w = (eye + forward) / fs.scale + fs.origin
        return Camera.look_at(tuple(eye_w), tuple(target_w), fov=fs.fov)


class FrameBudget:
    """Milliseconds of mesh uploads an interactive frame may spend (see the module
    docstring): ``margin_ms`` over the median of the last ``window`` frames' other work."""

    def __init__(self, margin_ms: float, window: int = 15) -> None:
        if not (math.isfinite(margin_ms) and margin_ms >= 0):
            raise InvalidParameterError(f"frame margin must be a number >= 0, got {margin_ms!r}.")
        self.margin_ms = float(margin_ms)
        #: Recent frame times without their mesh uploads (ms), oldest first.
        self.rest_ms: deque[float] = deque(maxlen=window)
        self._last_start: float | None = None
        self._last_upload_ms = 0.0

    def start(self, now_s: float) -> float | None:
        """A frame starts planning at ``now_s`` (seconds, a monotonic clock): the previous
        frame's time is recorded; returns its upload allowance in ms (None: no history yet,
        no limit)."""
        if self._last_start is not None:
            period = (now_s - self._last_start) * 1e3
            self.rest_ms.append(max(0.0, period - self._last_upload_ms))
        self._last_start = now_s
        self._last_upload_ms = 0.0
        return self.allowance_ms()

    def uploaded(self, ms: float) -> None:
        """This frame spent ``ms`` on mesh uploads."""
        self._last_upload_ms += float(ms)

    def allowance_ms(self) -> float | None:
        """Target (median rest + margin) less the last frame's rest, at least the margin (a
        frame heavy with texture uploads must not starve the cheap mesh uploads); None: no
        history."""
        if not self.rest_ms:
            return None
        target = float(np.median(self.rest_ms)) + self.margin_ms
        return max(self.margin_ms, target - self.rest_ms[-1])


class Prefetcher:
    """The MotionPredictor and FrameBudget of a tile source's interactive frames."""

    def __init__(self) -> None:
        self.motion = MotionPredictor()
        self.budget: FrameBudget | None = None

    def start(self, now_s: float, fs: FrameState, paging: Any, frozen: bool) -> float | None:
        """An interactive frame of ``fs`` plans at ``now_s`` (seconds) with ``paging`` (a
        Paging); ``frozen``: its cut is a frozen view's (nothing to predict). Returns the
        frame-time upload allowance in ms (None: no limit from the frame time)."""
        if not frozen:
            self.motion.observe(fs)
        margin = paging.frame_margin_ms
        if margin is None:
            self.budget = None
            return None
        if self.budget is None or self.budget.margin_ms != margin:
            self.budget = FrameBudget(margin)
        return self.budget.start(now_s)

    def uploaded(self, ms: float) -> None:
        """This frame spent ``ms`` on mesh uploads."""
        if self.budget is not None:
            self.budget.uploaded(ms)

    def views(self, fs: FrameState, paging: Any, bounds: np.ndarray) -> list[FrameState]:
        """The FrameStates to prefetch for, most likely first: the cameras of ``paging.path``
        (a fly-to path), then the camera extrapolated ``paging.lookahead`` frames ahead and
        twice that (a load slower than the lookahead still lands in time).
        bounds: (6,) the tree's root box (near/far)."""
        cameras = list(paging.path)
        for frames in (paging.lookahead, 2 * paging.lookahead) if paging.lookahead else ():
            predicted = self.motion.predict(fs, frames)
            if predicted is not None:
                cameras.append(predicted)
        return [
            FrameState.from_camera(cam, fs.viewport, bounds, fs.origin, fs.scale) for cam in cameras
        ]
