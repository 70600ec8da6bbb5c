"""The exception hierarchy: every error the engine raises on purpose derives from ApproxTreeError.

Each message says what was wrong and what to do about it, so the CLI can print it as it is.
"""

from __future__ import annotations


class ApproxTreeError(Exception):
    """Base class of every error approxtree raises for bad input or an unusable environment."""


class TerrainFormatError(ApproxTreeError):
    """A terrain file is missing, unreadable, of an unknown format, or malformed."""


class EmptyTerrainError(ApproxTreeError):
    """A terrain has too few valid data points to form a surface (all nodata, 1 × N, ...)."""


class InvalidParameterError(ApproxTreeError, ValueError):
    """A parameter is out of range (negative epsilon, max_points < 4, unknown policy, ...)."""


class UnsupportedStrategyError(ApproxTreeError):
    """The requested approximation strategy cannot be applied to this kind of terrain."""


class StoreError(ApproxTreeError):
    """A tree file is corrupted, truncated, of another format version, or cannot be written."""


class WholeBandError(ApproxTreeError):
    """An operation needs the whole height band of a windowed terrain, and it is too large.

    The message names the operation and what to do instead (work on a window, or open the
    raster in memory).
    """


class ContextUnavailableError(ApproxTreeError):
    """No OpenGL context can be created (headless EGL or a window)."""


class ApproxTreeWarning(UserWarning):
    """Base class of the warnings approxtree gives about input that is usable but suspicious.

    The CLI prints each as one ``Warning:`` line on stderr.
    """


class TerrainDataWarning(ApproxTreeWarning):
    """A terrain file reads, but its values look wrong (heights beyond the Earth's range, ...)."""
