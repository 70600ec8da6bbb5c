"""Cut: how a frame's cut of the tree is chosen, validated once where it is made.

One object instead of a set of flags (DESIGN.md, "Renderer roles"): every way of choosing the
nodes a frame draws is a field, checked in ``__post_init__`` (the only place the thresholds are
checked; ``select`` makes a Cut of the floats it is given), and a Cut never changes after.

- ``alpha``, ``gamma``: the thresholds of the visual geometric error α (px) and the visual
  texture error γ (px²; inf ignores it) that the traversal refines against;
- ``max_triangles``: a triangle budget instead of alpha (render/budget.py);
- ``full_resolution``: the unsimplified terrain instead of a cut (render/full_resolution.py);
- ``share_textures``: let nodes be drawn with an ancestor's texture patch (core paper, 4.2);
- ``frozen``: the FrameState to select for instead of the camera's (a frozen cut, looked at
  from elsewhere, as the viewer's freeze key does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.frame_state import FrameState


@dataclass(frozen=True)
class Cut:
    """How a frame's cut is chosen (see the module docstring).

    alpha: α threshold (px, > 0, finite); gamma: γ threshold (px², > 0, inf ignores it);
    max_triangles: triangle budget instead of alpha (the cut of smallest largest α with at
    most this many triangles, skirts included), or None; full_resolution: the unsimplified
    terrain; share_textures: nodes may use an ancestor's texture patch (off only to measure
    what sharing saves); frozen: a FrameState to select for instead of the camera's, or None.
    """

    alpha: float = 1.0
    gamma: float = 2.0
    max_triangles: int | None = None
    full_resolution: bool = False
    share_textures: bool = True
    frozen: FrameState | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for name, inf_ok in (("alpha", False), ("gamma", True)):
            v = getattr(self, name)
            ok = isinstance(v, int | float | np.floating | np.integer) and not math.isnan(v)
            if not ok or v <= 0 or (math.isinf(v) and not inf_ok):
                raise InvalidParameterError(
                    f"{name} must be a {'number' if inf_ok else 'finite number'} of pixels > 0, "
                    f"got {v!r}."
                )
            object.__setattr__(self, name, float(v))
        budget = self.max_triangles
        if budget is not None and (
            isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget <= 0
        ):
            raise InvalidParameterError(
                f"max_triangles must be an int > 0 or None, got {budget!r}."
            )
        if self.frozen is not None and not isinstance(self.frozen, FrameState):
            raise InvalidParameterError(
                f"frozen must be a FrameState (Engine.frame_state) or None, got {self.frozen!r}."
            )
        object.__setattr__(self, "full_resolution", bool(self.full_resolution))
        object.__setattr__(self, "share_textures", bool(self.share_textures))
