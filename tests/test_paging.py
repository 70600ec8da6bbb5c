"""The paging renderer (provider, traversal, renderer) with caches of a few nodes' bytes.

Once loading has settled, the image equals the image drawn with everything resident, pixel for
pixel; the CPU and GPU caches never exceed their budgets; every frame drawn while loading is a
crack-free partition (checked on the node rects); stale requests are cancelled; release frees
everything. GL tests run on headless EGL (shared context, as in test_render.py).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from conftest import data_file

import approxtree as at
from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine, Paging, overview_camera
from approxtree.render.cache_keys import NODE, MeshKey, TextureKey
from approxtree.render.context import create_context
from approxtree.render.provider import Payload, PayloadProvider
from approxtree.render.selector import select

SIZE = (320, 240)


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the module (fails with the install hint without EGL)."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module", params=["fractal", "nc"])
def stored_tree(request, tmp_path_factory):
    """A tree saved and loaded again, so patches are read from the store on demand: a
    generated 257² fractal and a real 450 × 500 DEM (NC, 30 m)."""
    if request.param == "fractal":
        terrain = fractal_terrain(257, seed=11, relief=400.0)
        eps = 1.0
    else:
        data_dir = request.getfixturevalue("data_dir")
        terrain = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
        eps = 2.0
    tree = ApproximationTree.build(terrain, epsilon=eps, max_points=17 * 17, progress=False)
    path = tmp_path_factory.mktemp("paging") / f"{request.param}.zarr"
    tree.save(path)
    return at.load_tree(path)


def views(tree, scale) -> list[Camera]:
    """Overview, an oblique view close to the ground and a grazing one across the domain."""
    d = tree.terrain.domain
    (cx, cy), w = d.center, d.xmax - d.xmin
    top = float(tree.bboxes[0][5])
    return [
        overview_camera(tree.bboxes[0], scale),
        Camera.look_at((cx - 0.3 * w, cy - 0.45 * w, top + 0.1 * w), (cx, cy, top - 0.1 * w)),
        Camera.look_at((d.xmin, d.ymin, top + 0.02 * w), (cx, cy + 0.2 * w, top - 0.05 * w)),
    ]


def payload_bytes(engine: Engine) -> np.ndarray:
    """(n,) bytes of every node's payload (mesh with skirts), as uploaded."""
    build = engine.provider.loader  # builds a payload without caching it
    return np.array([build(MeshKey(NODE, i)).nbytes for i in range(len(engine.tree))])


def record_blocking_loads(engine: Engine):
    """(keys, render): ``render(...)`` is ``engine.render`` recording into ``keys`` the
    payloads loaded on the frame's own thread during the call (a blocking read)."""
    main = threading.current_thread()
    blocking: list = []
    inside = [False]
    load = engine.provider.loader

    def loader(key):
        if inside[0] and threading.current_thread() is main:
            blocking.append(key)
        return load(key)

    def render(*args, **kwargs):
        inside[0] = True
        try:
            return engine.render(*args, **kwargs)
        finally:
            inside[0] = False

    engine.provider.loader = loader
    return blocking, render


def ancestors_or_self(parents: np.ndarray, node: int) -> list[int]:
    out = [node]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


def assert_partition(tree, wanted: np.ndarray, drawn: np.ndarray) -> None:
    """The drawn nodes tile the wanted cut's area: their rects never overlap, and each wanted
    node's rect lies inside exactly one drawn rect (itself or an ancestor's)."""
    rects = tree.rects[drawn]
    ix = np.minimum(rects[:, None, 2], rects[None, :, 2]) - np.maximum(
        rects[:, None, 0], rects[None, :, 0]
    )
    iy = np.minimum(rects[:, None, 3], rects[None, :, 3]) - np.maximum(
        rects[:, None, 1], rects[None, :, 1]
    )
    overlap = (np.clip(ix, 0, None) * np.clip(iy, 0, None))[~np.eye(len(drawn), dtype=bool)]
    assert not (overlap > 0).any(), "drawn nodes overlap"
    w = tree.rects[wanted]
    inside = (
        (rects[None, :, 0] <= w[:, None, 0])
        & (rects[None, :, 1] <= w[:, None, 1])
        & (rects[None, :, 2] >= w[:, None, 2])
        & (rects[None, :, 3] >= w[:, None, 3])
    )
    assert (inside.sum(axis=1) == 1).all(), "a wanted node is covered by no drawn node (a gap)"
    # And nothing else is drawn: each drawn node is a wanted node or an ancestor of one.
    covering = {a for n in wanted.tolist() for a in ancestors_or_self(tree.parents, n)}
    assert set(drawn.tolist()) <= covering


def test_settled_image_with_tiny_caches_equals_everything_resident(gl_context, stored_tree):
    """With CPU and GPU caches of three nodes' bytes, a single image (wait=True) equals the
    image drawn with every payload resident, pixel for pixel, in every view."""
    tree = stored_tree
    with Engine(tree, context=gl_context, offscreen=True) as ref:
        budget = 3 * int(payload_bytes(ref).max())
        total = int(payload_bytes(ref).sum())
        cams = views(tree, ref.scale)
        # α alone refines an untextured cut: small enough for many patches in every view.
        refs = [ref.render(cam, SIZE, Cut(alpha=0.1)) for cam in cams]
    assert budget < total / 10
    with Engine(
        tree, context=gl_context, offscreen=True, cache_bytes=budget, cpu_cache_bytes=budget
    ) as tiny:
        for cam, want in zip(cams, refs, strict=True):
            frame = tiny.render(cam, SIZE, Cut(alpha=0.1))
            assert frame.stats["patches"] > 10
            assert np.array_equal(frame.selection.nodes, want.selection.nodes)
            assert np.array_equal(frame.image, want.image)
            assert tiny.cache.nbytes <= budget and tiny.provider.nbytes <= budget
        assert tiny.cache.evictions > 0 and tiny.provider.evictions > 0


def test_interactive_frames_settle_to_the_resident_image(gl_context, stored_tree):
    """Interactive frames (wait=False) draw stand-ins while the provider loads, each a
    crack-free partition; once nothing is pending the image equals the resident one."""
    tree = stored_tree
    with Engine(tree, context=gl_context, offscreen=True) as ref:
        cams = views(tree, ref.scale)
        sizes = payload_bytes(ref)
        refs = [ref.render(cam, SIZE) for cam in cams]
    # Caches that hold a view's cut and its ancestors but not the whole tree.
    need = max(
        int(sizes[np.unique(np.concatenate([ancestors_or_self(tree.parents, int(n)) for n in
                                             f.selection.nodes]))].sum())
        for f in refs
    )  # fmt: skip
    budget = need + need // 10
    assert budget < sizes.sum()
    with Engine(
        tree, context=gl_context, offscreen=True, cache_bytes=budget, cpu_cache_bytes=budget
    ) as eng:
        blocking, render = record_blocking_loads(eng)
        stand_ins = 0
        for cam, want in zip(cams, refs, strict=True):
            for _ in range(200):
                frame = render(cam, SIZE, paging=Paging(wait=False, max_uploads=8))
                assert_partition(tree, want.selection.nodes, frame.selection.nodes)
                stand_ins += frame.stats["stand_ins"]
                if frame.stats["pending"] == 0:
                    break
                eng.provider.wait()  # the next frame finds this frame's request loaded
            assert frame.stats["pending"] == 0 and frame.stats["stand_ins"] == 0
            assert np.array_equal(frame.image, want.image)
        assert stand_ins > 0
        # Only the root was read on the frame's thread; everything else on loader threads.
        assert blocking == [MeshKey(NODE, 0)]


def test_budgets_hold_and_frames_stay_partitions_over_a_fly_over(gl_context, stored_tree):
    """A 50-frame fly-over with caches of four nodes' bytes: after every frame both caches are
    within budget, and the drawn nodes tile the wanted cut's area (no overlap, no gap)."""
    tree = stored_tree
    with Engine(tree, context=gl_context, offscreen=True) as probe:
        budget = 4 * int(payload_bytes(probe).max())
    d = tree.terrain.domain
    w = d.xmax - d.xmin
    top = float(tree.bboxes[0][5])
    with Engine(
        tree, context=gl_context, offscreen=True, cache_bytes=budget, cpu_cache_bytes=budget
    ) as eng:
        drawn_stand_ins = 0
        for k, t in enumerate(np.linspace(0.0, 1.0, 50)):
            x = d.xmin + (0.1 + 0.8 * t) * w
            y = d.ymin + 0.1 * w + 0.6 * w * t
            cam = Camera.look_at((x, y, top + 0.15 * w), (x + 0.2 * w, y + 0.3 * w, top - 0.1 * w))
            frame = eng.render(cam, SIZE, paging=Paging(wait=False, max_uploads=4))
            assert eng.cache.nbytes <= budget, f"GPU cache over budget at frame {k}"
            assert eng.provider.nbytes <= budget, f"CPU cache over budget at frame {k}"
            wanted = select(tree, frame.frame_state, 1.0, 2.0, eng.texels).nodes
            assert_partition(tree, wanted, frame.selection.nodes)
            drawn_stand_ins += frame.stats["stand_ins"] > 0
        assert drawn_stand_ins > 0
        # Patches were read from the store without being kept by the tree.
        held = sum(p is not None for p in tree._patches)
        assert held <= 1


def test_release_frees_everything(gl_context, stored_tree):
    """release() empties the GPU and CPU caches, stops the loader threads, frees targets."""
    tree = stored_tree
    eng = Engine(tree, context=gl_context, offscreen=True, cpu_cache_bytes=1 << 24)
    cam = overview_camera(tree.bboxes[0], eng.scale)
    eng.render(cam, SIZE, paging=Paging(wait=False))
    eng.render(cam, SIZE)
    assert len(eng.cache) > 0 and eng.provider.nbytes > 0
    eng.release()
    assert eng.released and len(eng.cache) == 0 and eng.cache.nbytes == 0
    assert eng.provider.closed and len(eng.provider) == 0 and eng.provider.nbytes == 0
    assert eng.provider._pool is None and not eng.renderer.targets


# -- the provider alone (no GL) ---------------------------------------------------------------


def _payload(n: int) -> Payload:
    return Payload(np.zeros((n, 4), np.float32), np.zeros((n, 3), np.uint32))


def test_provider_counts_bytes_exactly_and_evicts_least_recently_used():
    """Cache bytes are the payloads' array bytes; the least recently used leave first; a
    payload larger than the budget is returned but not kept."""
    provider = PayloadProvider(lambda k: _payload(k), cache_bytes=28 * 25)
    for k in (10, 5, 8):
        provider.load(k)
    assert provider.nbytes == 28 * 23 and provider.keys() == [10, 5, 8]
    provider.get(10)
    provider.load(4)  # 28 * 27 > budget: the least recently used (5) leaves
    assert provider.keys() == [8, 10, 4] and provider.nbytes == 28 * 22
    assert provider.evictions == 1
    big = provider.load(30)
    assert big.nbytes == 28 * 30 and 30 not in provider and provider.nbytes <= 28 * 25
    f = provider.figures()
    assert f["hits"] == 1 and f["loads"] == 5 and f["bytes"] == provider.nbytes
    provider.close()
    assert provider.nbytes == 0 and len(provider) == 0


def test_stale_requests_are_cancelled():
    """A new request cancels the keys of the previous one that were not started: they are
    never loaded; the key in flight finishes; the new keys load coarsest (first) first."""
    gate = threading.Event()
    started = threading.Event()
    loaded: list[str] = []

    def loader(key: str) -> Payload:
        if key == "a":
            started.set()
            gate.wait()
        loaded.append(key)
        return _payload(1)

    provider = PayloadProvider(loader, cache_bytes=1 << 20, threads=1)
    provider.request(list("abcdefgh"))
    started.wait()
    provider.request(["x", "c", "y"])
    assert provider.cancelled == 6  # b, d, e, f, g, h
    gate.set()
    provider.wait()
    assert sorted(loaded) == ["a", "c", "x", "y"]
    assert provider.is_resident(list("axcyb")).tolist() == [True] * 4 + [False]
    provider.close()


def test_textured_tiny_caches_settle_to_the_resident_image(gl_context, tmp_path):
    """With a texture pyramid, texture patches page through the same CPU cache: with tiny
    caches a single image, and interactive frames once settled, equal the resident image."""
    from approxtree.textures import TexturePyramid, TopographicShading

    terrain = fractal_terrain(257, seed=3, relief=300.0)
    tree = ApproximationTree.build(terrain, epsilon=1.0, max_points=17 * 17, progress=False)
    pyramid = TexturePyramid.build(TopographicShading(terrain), tmp_path, max_texture_size=64)
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as ref:
        budget = 3 * int(payload_bytes(ref).max())
        cams = views(tree, ref.scale)
        refs = [ref.render(cam, SIZE) for cam in cams]
    with Engine(
        tree,
        textures=pyramid,
        context=gl_context,
        offscreen=True,
        cache_bytes=budget,
        cpu_cache_bytes=budget,
    ) as tiny:
        loaded = []
        load = tiny.provider.loader
        tiny.provider.loader = lambda key: loaded.append(key) or load(key)
        for cam, want in zip(cams, refs, strict=True):
            assert want.stats["texture_patches"] > 1
            frame = tiny.render(cam, SIZE)
            assert np.array_equal(frame.image, want.image)
            assert tiny.cache.nbytes <= budget and tiny.provider.nbytes <= budget
        assert any(isinstance(k, TextureKey) for k in loaded) and tiny.provider.evictions > 0
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        blocking, render = record_blocking_loads(eng)
        root_tex = TextureKey.of(eng.texture_patch(0))
        texture_stand_ins = 0
        for cam, want in zip(cams, refs, strict=True):
            for _ in range(200):
                frame = render(cam, SIZE, paging=Paging(wait=False, max_uploads=8))
                texture_stand_ins += frame.stats["texture_stand_ins"]
                if frame.stats["pending"] == 0 and frame.stats["texture_stand_ins"] == 0:
                    break
                eng.provider.wait()
            assert np.array_equal(frame.image, want.image)
        # Interactive frames read the store on the frame's thread only for the root's mesh
        # and texture patch; texture patches not loaded yet were stood in for by the root's.
        assert set(blocking) <= {MeshKey(NODE, 0), root_tex} and texture_stand_ins > 0


def test_a_failed_background_load_fails_the_next_frame():
    """An error met on a loader thread (a corrupted chunk) is raised to the caller, once,
    instead of the node being requested and stood in for forever."""
    from approxtree.errors import StoreError

    def loader(key: int) -> Payload:
        if key == 3:
            raise StoreError("checksum mismatch in the patch of node 3")
        return _payload(1)

    provider = PayloadProvider(loader, cache_bytes=1 << 20, threads=1)
    provider.request([1, 3, 2])
    with pytest.raises(StoreError, match="node 3"):
        provider.wait()
    provider.wait()  # raised once
    provider.raise_error()
    assert provider.is_resident([1, 2, 3]).tolist() == [True, True, False]
    provider.close()
