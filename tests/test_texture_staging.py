"""Texture patches written over frames: the CPU mip chain and the GPU cache's staged uploads."""

from __future__ import annotations

import numpy as np
import pytest

from approxtree.render.context import create_context
from approxtree.render.gpu_cache import (
    GpuCache,
    mip_chain,
    mipmap_bytes,
    staged_uploads_available,
)


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the module (fails with the install hint without EGL)."""
    ctx = create_context()
    yield ctx
    ctx.release()


def test_mip_chain_is_the_rounded_box_mean_down_to_one_texel():
    """Each level is the 2 × 2 mean (half up) of the one above, sized as GL sizes levels."""
    rng = np.random.default_rng(0)
    texels = rng.integers(0, 256, (6, 11, 4), dtype=np.uint8)
    levels = mip_chain(texels)
    assert [a.shape[:2] for a in levels] == [(6, 11), (3, 5), (1, 2), (1, 1)]
    assert levels[0] is texels
    a = texels[:6, :10].astype(int)
    want = (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2] + 2) // 4
    assert np.array_equal(levels[1], want)
    # A side of one texel pairs with itself.
    b = levels[2].astype(int)
    assert np.array_equal(levels[3][0, 0], (2 * b[0, 0] + 2 * b[0, 1] + 2) // 4)


def test_staged_texture_is_drawable_only_once_every_level_is_written(gl_context):
    """A staged texture stays out of the cache until its last row is written, in steps of
    the bytes asked for; then it is an entry holding level 0's texels with its mip bytes."""
    if not staged_uploads_available():
        pytest.skip("no GL library to write mip levels with")
    cache = GpuCache(gl_context, 1 << 30)
    texels = np.random.default_rng(1).integers(0, 256, (64, 32, 4), dtype=np.uint8)
    cache.stage_texture("t", mip_chain(texels))
    steps = 0
    while "t" not in cache:
        assert cache.is_staged("t")
        cache.upload_staged(budget_ms=0.0, step_bytes=16 * 32 * 4)
        steps += 1
    # Level 0 in 4 steps of 16 rows, then one step per smaller level (7 levels: 6 more).
    assert steps == 4 + 6 and not cache.is_staged("t")
    entry = cache.get_texture("t", lambda: texels)
    assert entry.nbytes == mipmap_bytes(32, 64)
    got = np.frombuffer(entry.texture.read(), dtype=np.uint8).reshape(64, 32, 4)
    assert np.array_equal(got, texels)
    cache.stage_texture("u", mip_chain(texels))
    assert cache.unstage(lambda key: key == "u") == 1 and not cache.is_staged("u")
    cache.release()


def test_a_forgotten_texture_is_never_staged_from_stale_texels(gl_context):
    """A re-bake forgets the patches being prepared: their old mip chains are not written."""
    if not staged_uploads_available():
        pytest.skip("no GL library to write mip levels with")
    from approxtree.render.renderer import Renderer

    renderer = Renderer(gl_context, 1 << 30, owns_context=False)
    renderer.at_once_bytes = 0  # every patch written over frames
    try:
        texels = np.zeros((16, 16, 4), dtype=np.uint8)
        assert not renderer.texture_drawable("t", lambda: texels)
        renderer.forget_textures(lambda key: key == "t")
        for _ in range(3):
            renderer.step_textures(budget_ms=100.0)
        assert "t" not in renderer.cache and not renderer.cache.is_staged("t")
        # Wanted again, it is prepared afresh and becomes drawable within a few frames.
        fresh = np.full((16, 16, 4), 7, dtype=np.uint8)
        frames = 0
        while not renderer.texture_drawable("t", lambda: fresh):
            renderer.wait_textures()
            renderer.step_textures(budget_ms=100.0)
            frames += 1
            assert frames <= 2
        got = renderer.cache.get_texture("t", lambda: fresh).texture.read()
        assert np.array_equal(np.frombuffer(got, dtype=np.uint8).reshape(16, 16, 4), fresh)
    finally:
        renderer.release()


def test_small_patches_are_drawable_when_their_texels_arrive(gl_context):
    """A patch within ``at_once_bytes`` is uploaded whole in the frame its texels arrive,
    with the CPU mip chain; one still loading (texels None) is not drawable."""
    from approxtree.render.renderer import Renderer

    renderer = Renderer(gl_context, 1 << 30, owns_context=False)
    try:
        texels = np.random.default_rng(2).integers(0, 256, (32, 32, 4), dtype=np.uint8)
        assert not renderer.texture_drawable("s", lambda: None)
        assert renderer.texture_drawable("s", lambda: texels)
        assert "s" in renderer.cache and not renderer.cache.is_staged("s")
        got = renderer.cache.get_texture("s", lambda: texels).texture.read()
        assert np.array_equal(np.frombuffer(got, dtype=np.uint8).reshape(32, 32, 4), texels)
    finally:
        renderer.release()


def test_a_late_patch_is_finished_whatever_the_budget(gl_context):
    """A large patch wanted in every frame since its texels arrived is drawable after
    TEXTURE_LATE_STEPS frames even with no upload budget: the bound on settling."""
    if not staged_uploads_available():
        pytest.skip("no GL library to write mip levels with")
    from approxtree.render.renderer import TEXTURE_LATE_STEPS, Renderer

    renderer = Renderer(gl_context, 1 << 30, owns_context=False)
    renderer.at_once_bytes = 0
    try:
        # 2048² RGBA and its mips: 21 MB, six 4 MB steps at one step a frame without the rule.
        texels = np.random.default_rng(3).integers(0, 256, (2048, 2048, 4), dtype=np.uint8)
        frames = 0
        while not renderer.texture_drawable("big", lambda: texels):
            renderer.step_textures(budget_ms=0.0)
            frames += 1
        # Finished by the rule, not by the steps (six would be needed).
        assert frames == TEXTURE_LATE_STEPS + 1 < 6
        got = renderer.cache.get_texture("big", lambda: texels).texture.read()
        assert np.array_equal(np.frombuffer(got, dtype=np.uint8).reshape(2048, 2048, 4), texels)
    finally:
        renderer.release()
