"""Rate–distortion approximations on the embedded right-triangle binary tree (Balmelli et al.).

``decimate(grid)`` (constrained G-BFOS) and ``refine(grid)`` (greedy growing) return embedded
sequences of conforming meshes; ``rd_curves`` compares them with the uniform grid, greedy TIN
and RTIN at given triangle counts.
"""

from approxtree.rd.bintree import BinTree, lattice_heights
from approxtree.rd.curves import METHODS, rd_curves, snr_db
from approxtree.rd.sequence import EmbeddedSequence, decimate, refine, uniform

__all__ = [
    "METHODS",
    "BinTree",
    "EmbeddedSequence",
    "decimate",
    "lattice_heights",
    "rd_curves",
    "refine",
    "snr_db",
    "uniform",
]
