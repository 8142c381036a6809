"""Fixes found while probing ``cgvqm`` (issue 14, item 6)."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from cgvqm_core import CGVQMError
from cgvqm_core.cli import main
from cgvqm_core.stream import open_input
from cgvqm_core.weights import load_weights
from stimuli_manifests import write_video


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("alpha", [-40.0, 0.0])
def test_non_positive_alpha_is_refused(tmp_path, alpha):
    omega = torch.rand(1, 131, 1, 1, 1) / 131
    p = tmp_path / "w.pickle"
    p.write_bytes(pickle.dumps([omega, torch.tensor(alpha)], protocol=4))
    with pytest.raises(CGVQMError, match="positive scale alpha"):
        load_weights(p)
    j = tmp_path / "w.json"
    j.write_text(json.dumps({"format": "cgvqm-weights/1", "alpha": alpha,
                             "omega": [1 / 131] * 131}))
    with pytest.raises(CGVQMError, match="positive scale alpha"):
        load_weights(j)


def test_weights_info_with_list_provenance_is_one_line(capsys, tmp_path):
    j = tmp_path / "w.json"
    j.write_text(json.dumps({"format": "cgvqm-weights/1", "alpha": 2.0,
                             "omega": [1 / 131] * 131, "provenance": ["a", "b"]}))
    rc, _, err = _run(capsys, "weights", "info", j)
    assert rc == 2 and "provenance" in err and "Traceback" not in err


def _png_folder(path: Path, bits: int) -> Path:
    path.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        if bits == 16:
            arr = (rng.integers(0, 65535, (12, 16, 3))).astype(">u2")
            # PIL cannot write 16-bit RGB; write the PNG through a raw 16-bit encoder
            import zlib

            raw = b"".join(b"\0" + row.tobytes() for row in arr)
            def chunk(t: bytes, d: bytes) -> bytes:
                return (len(d).to_bytes(4, "big") + t + d
                        + zlib.crc32(t + d).to_bytes(4, "big"))
            png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", (16).to_bytes(4, "big")
                   + (12).to_bytes(4, "big") + bytes([16, 2, 0, 0, 0]))
                   + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
            (path / f"{i:03d}.png").write_bytes(png)
        else:
            Image.fromarray(rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)).save(
                path / f"{i:03d}.png")
    return path


def test_sixteen_bit_png_folder_is_not_silently_8_bit(tmp_path, caplog):
    deep = _png_folder(tmp_path / "deep", 16)
    with pytest.raises(CGVQMError, match="16-bit PNG"):
        open_input(deep, on_conversion="error")
    src = open_input(deep, on_conversion="warn")
    assert "16-bit PNG" in caplog.text and next(iter(src.frames())).dtype == np.uint8
    plain = _png_folder(tmp_path / "plain", 8)
    open_input(plain, on_conversion="error")  # 8-bit passes strict mode


def test_uniform_weights_are_flagged_in_text_and_json(capsys, tmp_path, vids):
    ref = vids.smooth(1, 6, 16, 20)
    r = write_video(tmp_path / "r.mkv", ref, 6)
    t = write_video(tmp_path / "t.mkv", vids.distort(ref, 2), 6)
    base = ["score", "--ref", r, "--test", t, "--random-backbone", "0", "--weights", "uniform"]
    rc, out, _ = _run(capsys, *base)
    assert rc == 0 and "[RANDOM BACKBONE]" in out and "[UNIFORM WEIGHTS]" in out
    rc, out, _ = _run(capsys, *base, "--json")
    doc = json.loads(out)
    assert doc["uniform_weights"] and doc["random_backbone"]
    assert "RANDOM backbone" in doc["warning"] and "UNIFORM feature weights" in doc["warning"]
