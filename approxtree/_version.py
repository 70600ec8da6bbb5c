"""The version of approxtree: its one source (pyproject.toml reads it, the package root and the
stores' ``library`` attribute import it). The bottom of the package: it imports nothing."""

__version__ = "0.1.0"
