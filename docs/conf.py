"""Sphinx configuration of approxtree's documentation site.

Build: ``sphinx-build -W --keep-going -n -b html docs docs/_build/html`` (what .ci/run runs).
The gallery (examples/gallery) runs at build time, offscreen through EGL; the real data come
from ../shared/data beside the project (or APPROXTREE_DATA); the examples that need them say
so on their page when they are absent. The API pages are written from the packages' __all__
by _ext/api_pages.py before the build reads them.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from sphinx_gallery.sorting import FileNameSortKey

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT))

# Pictures are drawn by the offscreen EGL engine; matplotlib without a display.
os.environ.setdefault("MPLBACKEND", "Agg")

import approxtree  # noqa: E402

# Say once, at the start of the build, whether the gallery's real data are there (not a
# warning: a build without them is still a valid build, with placeholders).
DATA = Path(os.environ.get("APPROXTREE_DATA", ROOT.parent / "shared" / "data"))
if not DATA.is_dir():
    print(
        f"approxtree docs: real data NOT FOUND at {DATA} (set APPROXTREE_DATA); the gallery "
        "examples that need them show a placeholder instead of their pictures.",
        file=sys.stderr,
    )
else:
    print(f"approxtree docs: real data from {DATA}", file=sys.stderr)

project = "approxtree"
author = "the approxtree developers"
copyright = "approxtree developers, MIT licence"
release = approxtree.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_click",
    "sphinx_copybutton",
    "sphinx_gallery.gen_gallery",
    "api_pages",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
# Command lines keep their "--" (no typographic dashes or quotes).
smartquotes = False
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "gallery/*.ipynb", "gallery/*.zip"]
templates_path = ["_templates"]

# MyST: ``:::`` fences, definition lists, anchors for headings.
myst_enable_extensions = ["colon_fence", "deflist", "attrs_inline"]
myst_heading_anchors = 3

# Every cross-reference must resolve (internal links are checked); references into other
# projects (numpy, moderngl, zarr, ...) are not linked: the CI machine has no internet for
# intersphinx inventories.
nitpicky = True
nitpick_ignore_regex = [
    (
        r"py:.*",
        r"(numpy|np|numpy\.typing|npt|moderngl|zarr|rasterio|affine|dask|distributed"
        r"|pyproj|shapely|trimesh|pyvista|xarray|PIL|click|tqdm|glfw|imgui_bundle|pathlib"
        r"|os|io|typing|collections|collections\.abc|concurrent|threading|enum|dataclasses"
        r"|fsspec|abc|t|matplotlib|scipy|numba|laspy|pyogrio|jupyter_rfb|contextlib|types)(\..*)?",
    ),
    # Builtins and typing aliases autodoc writes from annotations.
    (
        r"py:(class|obj|data)",
        r"(Any|Callable|Iterator|Iterable|Sequence|Mapping|Literal"
        r"|Path|PathLike|NDArray|ArrayLike|DTypeLike|Self|TypeAlias|ndarray|Affine|Context"
        r"|Framebuffer|Texture|DataArray|Client|Array|Image|Transformer|CRS|Geometry"
        r"|optional|callable|array_like|default|function|dict\[str)",
    ),
    # Private classes in public signatures: the storage sources ApproximationTree.load makes,
    # private bases, and internal records (a pyramid's deltas, a build's store regions, an
    # update's per-cell figures) that the API pages do not list.
    (
        r"py:class",
        r"(.*\.)?(_\w+|TreeFile|TreeStoreSource|PyramidDelta|HeightRegions|CellCache"
        r"|CompiledMeshArrays)",
    ),
]

# autodoc: members in source order, type hints in the signature, short names.
autodoc_default_options = {
    "members": True,
    "member-order": "bysource",
    "show-inheritance": True,
}
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = True
autodoc_class_signature = "mixed"
autodoc_mock_imports: list[str] = []
autosummary_generate = False
add_module_names = False
python_use_unqualified_type_names = True

html_theme = "pydata_sphinx_theme"
html_title = f"approxtree {release}"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_logo = None
html_theme_options = {
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "header_links_before_dropdown": 8,
    "secondary_sidebar_items": ["page-toc", "sourcelink"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
# Pages without sub-pages have no section navigation: no left sidebar.
html_sidebars = {
    name: []
    for name in ("index", "getting-started", "cli", "benchmarks", "development", "changelog")
}
html_show_sourcelink = False

copybutton_prompt_text = r"\$ |>>> "
copybutton_prompt_is_regexp = True

# The gallery: every example runs at build time (offscreen), pictures scraped from matplotlib
# figures; the examples write their own PNGs next to them and show them with matplotlib.
sphinx_gallery_conf = {
    "examples_dirs": [str(ROOT / "examples" / "gallery")],
    "gallery_dirs": ["gallery"],
    "filename_pattern": r"/plot_",
    "ignore_pattern": r"(__init__|_gallery)\.py",
    "within_subsection_order": FileNameSortKey,
    "image_scrapers": ("matplotlib",),
    "download_all_examples": False,
    "remove_config_comments": True,
    "show_memory": False,
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "min_reported_time": 1,
    "reset_modules": ("matplotlib",),
    "matplotlib_animations": False,
}

suppress_warnings = ["config.cache"]
