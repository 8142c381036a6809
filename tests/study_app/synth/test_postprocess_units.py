"""The post-processing steps against values known without running them."""

from __future__ import annotations

import math

import numpy as np

from study_app.synth.color import to_display
from study_app.synth.denoise import atrous_denoise
from study_app.synth.interpolate import interpolate_frames
from study_app.synth.splats import render_splats, splat_sequence
from study_app.synth.upscale import TemporalUpscaler, halton
from study_app.synth.vrs import RATE_COST, assign_rates, coarse_shade


def test_display_transfer_known_values():
    x = np.array([[0.0, math.log(2.0), 50.0]] * 3).T  # tone-mapped to 0, 0.5, ~1
    out = to_display(x)
    # sRGB(0.5) = 1.055 * 0.5 ** (1 / 2.4) - 0.055 = 0.7354 -> 187.5 -> 188
    assert out[:, 0].tolist() == [0, 188, 255]


def test_halton_known_values():
    assert [halton(i, 2) for i in (1, 2, 3, 4)] == [0.5, 0.25, 0.75, 0.125]
    assert math.isclose(halton(1, 3), 1 / 3) and math.isclose(halton(2, 3), 2 / 3)


def test_blending_interpolates_linearly_between_rendered_frames():
    frames = [np.full((2, 2, 3), float(i), dtype=np.float32) for i in range(16)]
    out = interpolate_frames(frames, step=5, count=11)
    assert [float(f[0, 0, 0]) for f in out] == [float(i) for i in range(11)]
    assert out[5] is frames[5]


def test_vrs_rates_meet_budgets_coarsening_low_contrast_first():
    rng = np.random.default_rng(1)
    contrast = rng.random((6, 5))
    n = contrast.size
    assert np.all(assign_rates(contrast, 1.0) == 1)
    assert np.all(assign_rates(contrast, 0.25) == 2)
    assert np.all(assign_rates(contrast, 0.0625) == 4)
    rates = assign_rates(contrast, 0.5)
    # 1 - k * 3/4 / n <= 0.5  ->  k = ceil(2n/3) tiles at 2x2, the lowest-contrast ones
    k = math.ceil(2 * n / 3)
    assert np.sum(rates == 2) == k and np.sum(rates == 4) == 0
    assert contrast[rates == 2].max() <= contrast[rates == 1].min()
    cost = np.mean([RATE_COST[int(r)] for r in rates.ravel()])
    assert cost <= 0.5


def test_coarse_shading_averages_blocks():
    img = np.arange(8 * 16 * 3, dtype=np.float32).reshape(8, 16, 3)
    rates = np.array([[4, 1]])
    out = coarse_shade(img, rates, tile=8)
    np.testing.assert_array_equal(out[:, 8:], img[:, 8:])
    np.testing.assert_allclose(out[0, 0], img[0:4, 0:4].mean(axis=(0, 1)))
    assert np.all(out[4:8, 4:8] == out[4, 4])


def test_upscaler_is_exact_at_scale_one_without_motion():
    rng = np.random.default_rng(2)
    img = rng.random((8, 12, 3)).astype(np.float32)
    up = TemporalUpscaler(12, 8)
    zero = np.zeros((8, 12, 2), dtype=np.float32)
    for _ in range(3):
        out = up.step(img, zero, (0.0, 0.0))
        np.testing.assert_allclose(out, img, atol=1e-6)


def test_splats_of_a_flat_image_are_flat():
    flat = [np.full((16, 16, 3), 0.3, dtype=np.float32)] * 3
    motion = [np.zeros((16, 16, 2), dtype=np.float32)] * 3
    for frame in splat_sequence(flat, motion, 16, 2, np.random.default_rng(0)):
        np.testing.assert_allclose(frame, 0.3, atol=1e-6)
    one = render_splats(np.array([8.0]), np.array([8.0]), np.array([[1.0, 2.0, 3.0]]), 16, 16, 2.0)
    np.testing.assert_allclose(one, np.broadcast_to([1.0, 2.0, 3.0], one.shape), rtol=1e-6)


def test_denoiser_keeps_noise_free_lighting_and_texture():
    rng = np.random.default_rng(3)
    albedo = rng.uniform(0.1, 0.9, size=(2, 16, 16, 3)).astype(np.float32)
    colour = albedo * 0.7  # constant irradiance 0.7, textured albedo
    normal = np.zeros((2, 16, 16, 3), dtype=np.float32)
    normal[..., 1] = 1.0
    depth = np.ones((2, 16, 16), dtype=np.float32)
    hit = np.ones((2, 16, 16), dtype=bool)
    out = atrous_denoise(colour, albedo, normal, depth, hit)
    np.testing.assert_allclose(out, colour, rtol=1e-5)
    # and it does reduce noise in the lighting
    noisy = albedo * (0.7 + rng.normal(0, 0.2, size=(2, 16, 16, 1)).astype(np.float32))
    den = atrous_denoise(noisy, albedo, normal, depth, hit)
    assert np.mean((den - colour) ** 2) < 0.3 * np.mean((noisy - colour) ** 2)
