"""
Rate–distortion: decimation, refinement and the rest
====================================================

Balmelli, Ayer and Vetterli's embedded right-triangle binary tree on a 257 × 257 window of
Crater Lake (the Garland & Heckbert test terrain): *decimation* (constrained G-BFOS) prunes
the full grid down to two triangles, *refinement* grows from two triangles; both give
embedded sequences of conforming meshes. Their signal-to-noise ratio and max error at each
triangle count, against the uniform grid, the greedy TIN and the RTIN. The same as
``approxtree rd scape/crater.stm --size 257 --rates 256,512,1024,2048,4096 --plot rd.png``.
"""

# %%
import matplotlib.pyplot as plt
from _gallery import data_file, placeholder

import approxtree as at
from approxtree.rd import lattice_heights, rd_curves

stm = data_file("scape/crater.stm")
if stm is None:
    placeholder("Crater Lake data absent (shared/data/scape): no curve")
else:
    heights = lattice_heights(at.open_terrain(stm), 257)
    rates = (256, 512, 1024, 2048, 4096)
    result = rd_curves(heights, rates)
    for name, method in result["methods"].items():
        print(f"{name:>10}: " + "  ".join(f"{r['snr_db']:6.2f}" for r in method["rows"]))

# %%
# SNR = 10 log10(e_max / e_m) (L2, left) and the largest error (L∞, right) per method.
if stm is not None:
    fig, (l2, linf) = plt.subplots(1, 2, figsize=(10, 4))
    for name, method in result["methods"].items():
        tri = [r["triangles"] for r in method["rows"]]
        l2.plot(tri, [r["snr_db"] for r in method["rows"]], "o-", ms=4, label=name)
        linf.plot(tri, [r["max_error"] for r in method["rows"]], "o-", ms=4, label=name)
    l2.set(xscale="log", xlabel="triangles", ylabel="SNR (dB)", title="L2")
    linf.set(xscale="log", yscale="log", xlabel="triangles", ylabel="max error (m)", title="L∞")
    for ax in (l2, linf):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()

# %%
# The decimated mesh of at most 1,024 triangles, on the lattice: conforming, finer where
# the crater's rim bends.
if stm is not None:
    decimation = result["sequences"]["decimation"]
    vx, vy, triangles = decimation.mesh(decimation.index_at_rate(1024))
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.imshow(heights, cmap="terrain")
    ax.triplot(vx, vy, triangles, color="black", lw=0.4)
    ax.set_title(f"decimation: {len(triangles)} triangles")
    ax.set_axis_off()
    print(
        "largest error of that mesh:",
        round(decimation.errors(decimation.index_at_rate(1024))[1], 2),
    )
