"""Each distortion family does what it claims, measured on the written videos."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from stimuli_manifests import load_manifest, read_video, validate_manifest
from study_app.synth import METHODS
from study_app.synth.methods import INTERPOLATED_FPS
from study_app.synth.vrs import TILE


def _videos(manifest_path):
    loaded = load_manifest(manifest_path)
    refs = {r.id: read_video(loaded.reference_path(r.id)).astype(np.float64)
            for r in loaded.manifest.references}
    by = defaultdict(dict)  # (scene, method) -> level -> (condition, frames)
    for c in loaded.manifest.conditions:
        frames = read_video(loaded.resolve(c.path)).astype(np.float64)
        by[(loaded.manifest.scene_of(c.reference), c.method)][c.level] = (c, frames)
    return loaded, refs, by


@pytest.fixture(scope="module")
def videos(tiny_study):
    return _videos(tiny_study)


def test_manifest_is_valid_and_complete(videos, tiny_study):
    loaded, refs, by = videos
    m = loaded.manifest
    report = validate_manifest(loaded, probe_videos=True)
    assert report.ok, report.errors
    assert not report.warnings  # every checksum is filled in
    scenes = {m.scene_of(r.id) for r in m.references}
    assert scenes == {"colonnade", "lattice"}
    # per scene: a 30 fps reference for five families, a 60 fps one for interpolation
    assert len(m.references) == 4
    assert len(m.conditions) == 2 * 6 * 4
    for (scene, method), levels in by.items():
        assert sorted(levels) == [1, 2, 3, 4], (scene, method)
        for level, (cond, frames) in levels.items():
            ref = refs[cond.reference]
            assert frames.shape == ref.shape
            assert cond.setting == METHODS[method].levels[level - 1].setting
            assert cond.id.startswith(cond.reference + "_HRC")
            fps = m.reference_by_id(cond.reference).fps
            assert fps == (INTERPOLATED_FPS if method == "frame_interpolation" else 30)
    hidden = [s for s in m.stimuli() if s.is_hidden_reference]
    assert len(hidden) == 4


def _mse(a, b):
    return float(np.mean((a - b) ** 2))


@pytest.mark.parametrize("method", ["path_tracing", "denoising", "upscaling", "vrs"])
def test_error_falls_with_level(videos, method):
    _, refs, by = videos
    for scene in ("colonnade", "lattice"):
        levels = by[(scene, method)]
        errors = [_mse(levels[lv][1], refs[levels[lv][0].reference]) for lv in (1, 2, 3, 4)]
        assert all(e > 0 for e in errors), (scene, method, errors)
        assert errors == sorted(errors, reverse=True), (scene, method, errors)
        assert errors[0] > 1.5 * errors[3], (scene, method, errors)


def test_noise_is_sampling_noise_not_bias(egl):
    """The 256-spp estimate converges to the reference: its mean error is tiny next to its
    spread, and the spread shrinks like 1/sqrt(spp) between 16 and 256 spp."""
    from study_app.synth.renderer import SceneRenderer, create_context

    ctx = create_context()
    try:
        r = SceneRenderer(ctx, "colonnade", 64, 64, seed=3)
        f = r.reference(0.3, 9, mc=True)
        r.release()
    finally:
        ctx.release()
    d16 = f.noisy[16] - f.reference
    d256 = f.noisy[256] - f.reference
    n = d256.size
    # mean over all pixels: within 4 standard errors of zero
    assert abs(d256.mean()) < 4 * d256.std() / np.sqrt(n)
    ratio = d16.std() / d256.std()
    assert 2.5 < ratio < 6.0  # sqrt(256 / 16) = 4; fireflies make it heavy-tailed


def test_interpolation_differs_only_in_interpolated_frames(videos):
    _, refs, by = videos
    for scene in ("colonnade", "lattice"):
        for level, (cond, frames) in by[(scene, "frame_interpolation")].items():
            ref = refs[cond.reference]
            step = INTERPOLATED_FPS // int(cond.metadata["parameter"])
            for i in range(len(frames)):
                same = np.array_equal(frames[i], ref[i])
                if i % step == 0:
                    assert same, (scene, level, i)
                else:
                    assert not same, (scene, level, i)


def test_vrs_blocks_are_constant_within_tiles_and_fit_the_budget(videos):
    by = videos[2]

    def constant_blocks(tile, b):
        t = tile.reshape(TILE // b, b, TILE // b, b, 3)
        return bool(np.all(t == t[:, :1, :, :1, :]))

    for scene in ("colonnade", "lattice"):
        for level, (cond, frames) in by[(scene, "vrs")].items():
            budget = float(cond.metadata["parameter"]) / 100.0
            h, w = frames.shape[1:3]
            for frame in frames:
                cost = []
                for y in range(0, h, TILE):
                    for x in range(0, w, TILE):
                        tile = frame[y : y + TILE, x : x + TILE]
                        if constant_blocks(tile, 4):
                            cost.append(1 / 16)
                        elif constant_blocks(tile, 2):
                            cost.append(1 / 4)
                        else:
                            cost.append(1.0)
                assert np.mean(cost) <= budget + 1e-9, (scene, level, np.mean(cost))
                if level == 1:  # 6.25 %: the whole frame is shaded once per 4x4 block
                    assert all(c == 1 / 16 for c in cost)


def _detail(frames):
    """Mean squared horizontal + vertical pixel differences: how much fine detail is left."""
    return float(np.mean(np.diff(frames, axis=1) ** 2) + np.mean(np.diff(frames, axis=2) ** 2))


def test_fewer_splats_blur_more(videos):
    _, refs, by = videos
    for scene in ("colonnade", "lattice"):
        levels = by[(scene, "splatting")]
        detail = [_detail(levels[lv][1]) for lv in (1, 2, 3, 4)]
        ref_detail = _detail(refs[levels[1][0].reference])
        assert detail == sorted(detail), (scene, detail)
        assert detail[3] < ref_detail


def test_reference_is_identical_to_a_rerender(videos, egl, tiny_options):
    from study_app.synth.build import _seed_for
    from study_app.synth.color import to_display
    from study_app.synth.renderer import SceneRenderer, create_context

    loaded, refs, _ = videos
    m = loaded.manifest
    ctx = create_context()
    try:
        for scene_index, scene in enumerate(("colonnade", "lattice")):
            ref60 = next(r for r in m.references
                         if r.scene == scene and r.fps == INTERPOLATED_FPS)
            renderer = SceneRenderer(ctx, scene, 64, 64,
                                     seed=_seed_for(tiny_options["seed"], scene_index) & 0xFFFFFFFF)
            for i in (0, 7):
                frame = renderer.reference(i / INTERPOLATED_FPS, i, mc=False).reference
                assert np.array_equal(to_display(frame), refs[ref60.id][i].astype(np.uint8))
            renderer.release()
    finally:
        ctx.release()
