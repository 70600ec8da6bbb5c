"""StrategyPolicy: which approximation strategy (patch type) builds each node.

A policy names, per node, the *candidate* strategies; the builder builds every candidate and the
policy ``choose``s one patch. Policies:

- fixed (``"grid"``, ``"tin"``, ...): one strategy for every node;
- ``"type"`` (the default): the strategy made for the terrain's data type — grid on a Grid, tin
  on a TIN or point set, and on a GridRefinement tin for the nodes holding microstructure data
  points and grid elsewhere (a regular grid cannot reproduce the microstructures);
- ``"auto"``: every strategy that can build the terrain's data type; per node the patch with the
  smallest memory (``nbytes``) among those meeting the node's error budget ε with at most s
  points, or, when none meets it, the one with the smallest error (the node is split anyway and
  the best approximation serves the coarse view);
- by level (``"level:grid@0-3,tin"``, ``StrategyPolicy.by_level``): a strategy per level range,
  the entry without ``@`` for every other level;
- by data semantics (``"semantic:tin@4,grid"``, ``StrategyPolicy.by_semantics``): a node whose
  domain holds microstructure data points uses the first strategy from the given level on, every
  other node the second (which may be ``auto``).

Strategy names come from the ``STRATEGIES`` registry at call time, so a strategy registered
later joins ``auto`` and the parsers without a change here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.patches import STRATEGIES, GeometryPatch, Strategy
from approxtree.patches.table import type_strategy


def _check_name(name: str) -> str:
    known = ["auto", "type", *STRATEGIES]
    if name not in known:
        raise InvalidParameterError(
            f"Unknown strategy {name!r}; choose one of: {', '.join(known)} "
            "(or a policy 'level:grid@0-3,tin' / 'semantic:tin@4,grid')."
        )
    return name


def choose_patch(patches: Sequence[GeometryPatch], epsilon: float) -> GeometryPatch:
    """The smallest patch (nbytes) with error <= epsilon, else the one of smallest error."""
    meeting = [p for p in patches if p.error <= epsilon]
    if meeting:
        return min(meeting, key=lambda p: (p.nbytes, p.error))
    return min(patches, key=lambda p: (p.error, p.nbytes))


class StrategyPolicy:
    """Chooses the patch class of a node from the terrain, the node's level and rectangle.

    name: a strategy name (fixed policy), ``"type"`` or ``"auto"``. Subclasses override
    ``candidates``.
    """

    def __init__(self, name: str = "type") -> None:
        self.name = _check_name(name)

    def candidates(self, terrain: GeometryData, level: int, rect: Rect) -> tuple[str, ...]:
        """Names of the strategies that may build the node at ``level`` covering ``rect``."""
        if self.name == "auto":
            return tuple(STRATEGIES)
        if self.name == "type":
            return _by_type(terrain, level, rect)
        return (self.name,)

    def candidates_level(
        self, terrain: GeometryData, level: int, rects: np.ndarray
    ) -> list[tuple[tuple[str, ...], np.ndarray]]:
        """``candidates`` of a whole level: (names, node indices (j,) int64) per group of nodes
        sharing their candidates; rects (k, 4) float64. Python runs per group, not per node."""
        everyone = np.arange(len(rects), dtype=np.int64)
        if type(self).candidates is not StrategyPolicy.candidates:
            # A subclass choosing per rectangle: ask it node by node, then group.
            per_node = [self.candidates(terrain, level, Rect(*b)) for b in rects.tolist()]
            groups: dict[tuple[str, ...], list[int]] = {}
            for i, names in enumerate(per_node):
                groups.setdefault(tuple(names), []).append(i)
            return [(n, np.array(i, dtype=np.int64)) for n, i in groups.items()]
        if self.name == "type":
            return _by_type_level(terrain, level, rects)
        return [(self.candidates(terrain, level, _NO_RECT), everyone)]

    def choose(self, patches: Sequence[GeometryPatch], epsilon: float) -> GeometryPatch:
        """The patch the node keeps among its candidates' patches (see ``choose_patch``)."""
        return choose_patch(patches, epsilon)

    def strategy_for(self, terrain: GeometryData, level: int, rect: Rect) -> Strategy:
        """The patch class of a node with a single candidate (the first one otherwise)."""
        return STRATEGIES[self.candidates(terrain, level, rect)[0]]

    @staticmethod
    def by_level(levels: dict[range, str], default: str) -> LevelPolicy:
        """Strategy per level range, e.g. ``by_level({range(0, 4): "grid"}, default="tin")``."""
        return LevelPolicy(list(levels.items()), default)

    @staticmethod
    def by_semantics(fine: str = "tin", other: str = "auto", from_level: int = 0):
        """Nodes holding microstructure points use ``fine`` from ``from_level`` on."""
        return SemanticPolicy(fine, other, from_level)

    @classmethod
    def parse(cls, text: str) -> StrategyPolicy:
        """A policy from its CLI form (see the module docstring)."""
        text = text.strip()
        if text.startswith("level:"):
            return LevelPolicy.parse(text[len("level:") :])
        if text.startswith("semantic:"):
            return SemanticPolicy.parse(text[len("semantic:") :])
        return cls(text)

    @classmethod
    def resolve(cls, policy: str | StrategyPolicy) -> StrategyPolicy:
        """A policy object from a name or an existing policy."""
        return policy if isinstance(policy, StrategyPolicy) else cls.parse(policy)


def _parse_levels(spec: str, text: str) -> range:
    """'3' → range(3, 4); '0-3' → range(0, 4); '4-' → range(4, ∞)."""
    try:
        lo, sep, hi = spec.partition("-")
        start = int(lo)
        stop = (int(hi) + 1 if hi else 1 << 30) if sep else start + 1
    except ValueError:
        raise InvalidParameterError(
            f"Bad level range {spec!r} in policy {text!r}; write e.g. grid@0-3 or tin@4-."
        ) from None
    if start < 0 or stop <= start:
        raise InvalidParameterError(f"Empty level range {spec!r} in policy {text!r}.")
    return range(start, stop)


class LevelPolicy(StrategyPolicy):
    """A strategy (or ``auto``) per range of levels, ``default`` for the others."""

    def __init__(self, ranges: list[tuple[range, str]], default: str) -> None:
        self.ranges = [(r, _check_name(n)) for r, n in ranges]
        self.default = _check_name(default)
        parts = [f"{n}@{r.start}-{'' if r.stop >= 1 << 30 else r.stop - 1}" for r, n in self.ranges]
        self.name = "level:" + ",".join([*parts, self.default])
        self._inner = {n: StrategyPolicy(n) for n in {self.default, *(n for _, n in ranges)}}

    def candidates(self, terrain: GeometryData, level: int, rect: Rect) -> tuple[str, ...]:
        name = next((n for r, n in self.ranges if level in r), self.default)
        return self._inner[name].candidates(terrain, level, rect)

    def candidates_level(
        self, terrain: GeometryData, level: int, rects: np.ndarray
    ) -> list[tuple[tuple[str, ...], np.ndarray]]:
        name = next((n for r, n in self.ranges if level in r), self.default)
        return self._inner[name].candidates_level(terrain, level, rects)

    @classmethod
    def parse(cls, spec: str) -> LevelPolicy:
        ranges: list[tuple[range, str]] = []
        default = None
        for entry in filter(None, (e.strip() for e in spec.split(","))):
            name, at, levels = entry.partition("@")
            if at:
                ranges.append((_parse_levels(levels, spec), name))
            elif default is None:
                default = name
            else:
                raise InvalidParameterError(
                    f"Policy 'level:{spec}' has two default strategies ({default}, {name}); "
                    "give levels to all but one, e.g. level:grid@0-3,tin."
                )
        if default is None:
            raise InvalidParameterError(
                f"Policy 'level:{spec}' needs a default strategy without @, "
                "e.g. level:grid@0-3,tin."
            )
        return cls(ranges, default)


def _by_type(terrain: GeometryData, level: int, rect: Rect) -> tuple[str, ...]:
    """The ``type`` policy: the strategy made for the terrain's data type."""
    from approxtree.geometry.refinement import GridRefinement

    name = type_strategy(terrain)
    if name is not None:
        return (name,)
    if isinstance(terrain, GridRefinement):
        return _MICRO_TIN.candidates(terrain, level, rect)
    # Any other data type: every strategy, the builder keeps those that accept it.
    return tuple(STRATEGIES)


def _by_type_level(
    terrain: GeometryData, level: int, rects: np.ndarray
) -> list[tuple[tuple[str, ...], np.ndarray]]:
    """``_by_type`` of a whole level (see ``StrategyPolicy.candidates_level``)."""
    from approxtree.geometry.refinement import GridRefinement

    if isinstance(terrain, GridRefinement):
        return _MICRO_TIN.candidates_level(terrain, level, rects)
    return [(_by_type(terrain, level, _NO_RECT), np.arange(len(rects), dtype=np.int64))]


#: Stands for the rectangle of policies whose candidates do not depend on it.
_NO_RECT = Rect(0.0, 0.0, 0.0, 0.0)


class SemanticPolicy(StrategyPolicy):
    """``fine`` for nodes from ``from_level`` on that hold microstructure data points."""

    def __init__(self, fine: str = "tin", other: str = "auto", from_level: int = 0) -> None:
        self.fine = _check_name(fine)
        self.other = _check_name(other)
        self.from_level = int(from_level)
        self.name = f"semantic:{self.fine}@{self.from_level},{self.other}"
        self._fine = StrategyPolicy(self.fine)
        self._other = StrategyPolicy(self.other)

    @staticmethod
    def holds_microstructure(terrain: GeometryData, rect: Rect) -> bool:
        """True when some microstructure vertex (a data point) lies in the closed ``rect``."""
        micro_index = getattr(terrain, "micro_index", None)
        return micro_index is not None and len(micro_index(rect)) > 0

    def candidates(self, terrain: GeometryData, level: int, rect: Rect) -> tuple[str, ...]:
        if level >= self.from_level and self.holds_microstructure(terrain, rect):
            return self._fine.candidates(terrain, level, rect)
        return self._other.candidates(terrain, level, rect)

    def candidates_level(
        self, terrain: GeometryData, level: int, rects: np.ndarray
    ) -> list[tuple[tuple[str, ...], np.ndarray]]:
        fine = np.zeros(len(rects), dtype=bool)
        if level >= self.from_level:
            # Microstructure terrains only: one index query per node.
            fine[:] = [
                self.holds_microstructure(terrain, Rect(*box)) for box in np.asarray(rects).tolist()
            ]
        groups = []
        for mask, inner in ((fine, self._fine), (~fine, self._other)):
            idx = np.flatnonzero(mask)
            if len(idx):
                groups += [
                    (n, idx[i]) for n, i in inner.candidates_level(terrain, level, rects[idx])
                ]
        return groups

    @classmethod
    def parse(cls, spec: str) -> SemanticPolicy:
        entries = [e.strip() for e in spec.split(",") if e.strip()]
        if len(entries) != 2 or "@" not in entries[0]:
            raise InvalidParameterError(
                f"Policy 'semantic:{spec}' must read FINE@LEVEL,OTHER, e.g. semantic:tin@4,grid."
            )
        fine, _, level = entries[0].partition("@")
        try:
            from_level = int(level)
        except ValueError:
            raise InvalidParameterError(
                f"Bad level {level!r} in policy 'semantic:{spec}'; write e.g. semantic:tin@4,grid."
            ) from None
        return cls(fine, entries[1], from_level)


_MICRO_TIN = SemanticPolicy("tin", "grid", 0)
