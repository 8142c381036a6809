"""Weights: safe decoding of the upstream pickles, sha256 checks, the project format."""

from __future__ import annotations

import hashlib
import os
import pickle

import numpy as np
import pytest
import torch

from cgvqm_core.errors import CGVQMError
from cgvqm_core.weights import (
    VARIANTS,
    FeatureWeights,
    fetch_upstream,
    load_upstream_pickle,
    load_weights,
    published_weights,
    resolve_weights,
    save_weights,
)


class _Evil:
    def __init__(self, target: str) -> None:
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch {self.target}",))


def test_malicious_pickle_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pickle"
    path.write_bytes(pickle.dumps([_Evil(str(marker)), torch.tensor(1.0)], protocol=4))
    with pytest.raises(CGVQMError, match="refused to load"):
        load_weights(path)
    assert not marker.exists()
    # the nested storage stream is decoded with weights_only too
    with pytest.raises(CGVQMError):
        load_upstream_pickle(_write(tmp_path / "evil2.pickle",
                                    pickle.dumps(_Evil(str(marker)), protocol=2)))
    assert not marker.exists()


def _write(path, data):
    path.write_bytes(data)
    return path


def test_own_pickle_in_upstream_format(tmp_path):
    """A pickled [omega, alpha] tensor pair (the upstream file layout) loads safely, and is
    not taken for the published weights: its metric is named after its file."""
    from cgvqm_core.metrics.cgvqm_entry import metric_name

    omega = torch.randn(1, 131, 1, 1, 1)
    path = _write(tmp_path / "w.pickle", pickle.dumps([omega, torch.tensor(7.5)], protocol=4))
    w = load_weights(path)
    assert w.variant == "cgvqm-2" and w.alpha == 7.5 and w.kind == "pickle"
    assert w.provenance == {"origin": str(path)}
    assert metric_name(type("M", (), {"weights": w, "variant": "cgvqm-2",
                                      "seamless": False})()) == "cgvqm-2-w"
    np.testing.assert_array_equal(w.omega, omega.reshape(-1).numpy())
    assert w.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    # a file named like a published one must carry its hash
    fake = _write(tmp_path / "cgvqm-2.pickle", path.read_bytes())
    with pytest.raises(CGVQMError, match="does not match"):
        resolve_weights(fake)


def test_upstream_files(upstream_dir):
    for name, n, levels in (("cgvqm-2", 131, 3), ("cgvqm-5", 1027, 6)):
        w = load_upstream_pickle(upstream_dir / f"{name}.pickle",
                                 expected_sha256=VARIANTS[name].sha256)
        assert w.variant == name and w.omega.shape == (n,) and w.n_levels == levels
        assert 0.3 < (w.omega < 0).mean() < 0.6  # about half negative: |omega| matters
        assert [len(x) for x in w.level_weights()] == [3, 64, 64, 128, 256, 512][:levels]
        assert all((x >= 0).all() for x in w.level_weights())


def test_fetch_from_local_folder_and_cache(upstream_dir):
    with pytest.raises(CGVQMError, match="weights fetch"):
        published_weights("cgvqm-2")  # offline, empty cache
    path = fetch_upstream("cgvqm-2", source_dir=upstream_dir)
    assert published_weights("cgvqm-2").sha256 == VARIANTS["cgvqm-2"].sha256
    assert path.is_file()


def test_fetch_refuses_wrong_hash(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    _write(src / "cgvqm-5.pickle", pickle.dumps([torch.randn(1, 1027, 1, 1, 1),
                                                 torch.tensor(1.0)]))
    with pytest.raises(CGVQMError, match="refusing"):
        fetch_upstream("cgvqm-5", source_dir=src)


def test_project_format_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    w = FeatureWeights("cgvqm-5", rng.normal(size=1027).astype(np.float32), 1234.5, "", "",
                       "project", {"datasets": ["CG-VQD"], "seed": 7})
    path = save_weights(tmp_path / "cal.json", w)
    assert path.read_text().lstrip().startswith("{")
    back = load_weights(path)
    np.testing.assert_array_equal(back.omega, w.omega)
    assert back.alpha == 1234.5 and back.variant == "cgvqm-5"
    assert back.provenance == {"datasets": ["CG-VQD"], "seed": 7}
    path.write_text(path.read_text().replace("cgvqm-weights/1", "cgvqm-weights/2"))
    with pytest.raises(CGVQMError, match="not supported"):
        load_weights(path)
