"""The registry finds the modules that declare metrics; the listing order is fixed."""

from __future__ import annotations

import importlib

from cgvqm_core.metrics import entries, get_entry, metric_table_rows
from cgvqm_core.metrics.registry import LISTING_GROUPS

LISTED = ["psnr", "ssim", "ms-ssim", "iw-ssim", "vif", "fsim", "sr-sim", "gmsd", "ms-gmsd",
          "vsi", "dss", "haarpsi", "mdsi", "flip", "lpips", "lpips-alex", "dists", "pieapp",
          "cvvdp", "vmaf", "cgvqm-2", "cgvqm-5"]


def test_listing_is_image_metrics_then_video_metrics_with_cgvqm_last():
    names = [e.spec.name for e in entries()]
    assert names == LISTED
    kinds = [e.spec.kind for e in entries()]
    assert kinds == sorted(kinds, key=["image", "video"].index)


def test_every_declaring_module_names_a_known_group_and_is_found():
    found = {type(e).__module__ for e in entries()}
    for name in found:
        module = importlib.import_module(name)
        assert module.LISTING_GROUP in LISTING_GROUPS
        assert all(get_entry(e.spec.name) is e for e in module.ENTRIES)


def test_table_rows_follow_the_listing_and_carry_the_spec():
    rows = metric_table_rows()
    assert [r["name"] for r in rows] == LISTED
    psnr = rows[0]
    assert (psnr["direction"], psnr["kind"], psnr["range"]) == ("higher-better", "image", "0..80")
    assert {"needs_weights", "available", "reason", "licence"} <= set(psnr)
