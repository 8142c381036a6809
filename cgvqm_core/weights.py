"""CGVQM's feature weights (omega) and scale (alpha): loading, verifying, fetching, saving.

Two file formats are read:

* the authors' pickles ``cgvqm-2.pickle`` / ``cgvqm-5.pickle`` (a list ``[omega, alpha]`` of
  tensors), decoded by an allow-list unpickler that refuses every global except the three
  the files use, so a malicious pickle cannot run code;
* the project format ``cgvqm-weights/1``: a JSON document (non-executable) holding omega,
  alpha, the variant and a provenance dict. Calibrations are saved in it.

The published pickles are fetched on first use from the authors' repository at a pinned
commit, checked against their sha256 and cached; offline, a local copy can be given.
"""

from __future__ import annotations

import collections
import hashlib
import io
import json
import logging
import math
import os
import pickle
import shutil
import tempfile
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch._utils

from .errors import CGVQMError

log = logging.getLogger(__name__)

UPSTREAM_COMMIT = "9872ccbabf68a9b878d032ea1abccd5ef10c855c"
UPSTREAM_URL = f"https://raw.githubusercontent.com/IntelLabs/cgvqm/{UPSTREAM_COMMIT}/weights/{{name}}"
PROJECT_FORMAT = "cgvqm-weights/1"
LEVEL_CHANNELS = (3, 64, 64, 128, 256, 512)


@dataclass(frozen=True)
class Variant:
    """A published CGVQM variant: how many levels it compares and its weights file."""

    name: str
    n_levels: int
    file_name: str
    sha256: str

    @property
    def n_channels(self) -> int:
        return sum(LEVEL_CHANNELS[: self.n_levels])


VARIANTS: dict[str, Variant] = {
    "cgvqm-2": Variant("cgvqm-2", 3, "cgvqm-2.pickle",
                       "18de1638b04886f972eb6534cc35a0e22ce9ebf26fa40689ba1e8130ea110f14"),
    "cgvqm-5": Variant("cgvqm-5", 6, "cgvqm-5.pickle",
                       "851ba1fcc92beddf4dd24c5bcfc1f2aa80f0f8b926b6b42fbffb2b0db7130cfd"),
}


def variant_for_channels(n: int, where: str | Path | None = None) -> Variant:
    """The variant whose levels have ``n`` channels in all (131 or 1027)."""
    for v in VARIANTS.values():
        if v.n_channels == n:
            return v
    prefix = f"{where}: " if where is not None else ""
    raise CGVQMError(
        f"{prefix}omega has {n} entries; CGVQM-2 needs {VARIANTS['cgvqm-2'].n_channels} and "
        f"CGVQM-5 {VARIANTS['cgvqm-5'].n_channels}"
    )


@dataclass
class FeatureWeights:
    """omega (one weight per channel of every level) and alpha, with where they came from."""

    variant: str
    omega: np.ndarray  # float32, (N,)
    alpha: float
    sha256: str
    source: str
    kind: str  # "upstream-pickle" (the published file) | "pickle" | "project" | "uniform"
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def n_levels(self) -> int:
        return VARIANTS[self.variant].n_levels

    def level_weights(self) -> list[np.ndarray]:
        """|omega| split per level (the metric uses the absolute values)."""
        cuts = np.cumsum(LEVEL_CHANNELS[: self.n_levels])[:-1]
        return np.split(np.abs(self.omega).astype(np.float32), cuts)


# -- safe decoding of the upstream pickles ---------------------------------------------------


def _storage_from_bytes(data: bytes) -> Any:
    """Stand-in for torch.storage._load_from_bytes that cannot execute code."""
    try:
        return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for refused or broken streams
        raise CGVQMError(f"refused a tensor storage inside the weights pickle ({exc})") from None


_ALLOWED: dict[tuple[str, str], Any] = {
    ("torch._utils", "_rebuild_tensor_v2"): torch._utils._rebuild_tensor_v2,
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch.storage", "_load_from_bytes"): _storage_from_bytes,
}


class _AllowListUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise CGVQMError(
                f"refused to load {module}.{name} from a weights pickle: only tensors are "
                "allowed (the file is not a CGVQM weights file or has been tampered with)"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise CGVQMError("refused a persistent id in a weights pickle (not a CGVQM weights file)")


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def load_upstream_pickle(path: str | Path, *, expected_sha256: str | None = None) -> FeatureWeights:
    """Decode an authors' ``[omega, alpha]`` pickle safely; verify its sha256 if given."""
    path = Path(path)
    data = _read(path)
    digest = sha256_bytes(data)
    if expected_sha256 is not None and digest != expected_sha256:
        raise CGVQMError(
            f"{path}: sha256 {digest} does not match the expected {expected_sha256}; the file "
            "is corrupt or not the published one (delete it and fetch again)"
        )
    try:
        obj = _AllowListUnpickler(io.BytesIO(data)).load()
    except CGVQMError:
        raise
    except Exception as exc:
        raise CGVQMError(f"{path}: not a readable CGVQM weights pickle ({exc})") from None
    if not (isinstance(obj, list | tuple) and len(obj) == 2
            and all(isinstance(t, torch.Tensor) for t in obj)):
        raise CGVQMError(f"{path}: expected a pickled [omega, alpha] pair of tensors")
    omega_t, alpha_t = obj
    if not (omega_t.is_floating_point() and alpha_t.is_floating_point()):
        raise CGVQMError(f"{path}: omega and alpha must be floating-point tensors, got "
                         f"{omega_t.dtype} and {alpha_t.dtype}")
    omega = omega_t.detach().reshape(-1).to(torch.float32).numpy().copy()
    if alpha_t.numel() != 1:
        raise CGVQMError(f"{path}: alpha must be a single number, got shape {tuple(alpha_t.shape)}")
    variant = variant_for_channels(omega.size, path)
    alpha = float(alpha_t.reshape(()))
    _check_values(path, omega, alpha)
    if digest == variant.sha256:
        return FeatureWeights(variant.name, omega, alpha, digest, str(path),
                              "upstream-pickle", {"origin": f"IntelLabs/cgvqm@{UPSTREAM_COMMIT}"})
    # the authors' format, but not their file (a calibration saved as their train.py does):
    # named after the file, so that its scores never pass for the published metric's
    log.warning("%s: weights in the authors' format but not the published %s ones (sha256 "
                "%s...); scored as %s-%s", path, variant.name, digest[:12], variant.name,
                path.stem)
    return FeatureWeights(variant.name, omega, alpha, digest, str(path), "pickle",
                          {"origin": str(path)})


def _check_values(path: Path, omega: np.ndarray, alpha: float) -> None:
    """Refuse weights that cannot give a meaningful q (non-finite, or alpha <= 0, which
    turns errors into gains and q above 100)."""
    if not (np.all(np.isfinite(omega)) and np.isfinite(alpha)):
        raise CGVQMError(f"{path}: omega/alpha contain non-finite numbers")
    if not alpha > 0:
        raise CGVQMError(f"{path}: alpha is {alpha:g}; CGVQM needs a positive scale alpha "
                         "(errors would count as gains and q exceed 100)")


# -- the project format ----------------------------------------------------------------------

_FLOAT32_MAX = float(np.finfo(np.float32).max)
_JSON_TYPES = {list: "array", dict: "object", str: "string", bool: "boolean",
               type(None): "null", int: "number", float: "number"}


def _json_type(value: Any) -> str:
    return _JSON_TYPES.get(type(value), type(value).__name__)


def _shown(value: Any) -> str:
    text = json.dumps(value) if _json_type(value) in _JSON_TYPES.values() else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _a(value: Any) -> str:
    """'an array ([1, 2])', 'a string ("x")', 'null': what a JSON value is, for messages."""
    kind = _json_type(value)
    if value is None:
        return "null"
    return f"{'an' if kind[0] in 'aeiou' else 'a'} {kind} ({_shown(value)})"


def _json_number(path: Path, name: str, value: Any) -> float:
    """A JSON number (not a string, boolean, array...) that is finite within float32."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CGVQMError(f"{path}: {name} is {_a(value)}, not a number")
    try:
        x = float(value)
    except OverflowError:  # an integer beyond any float
        x = math.inf
    if not (math.isfinite(x) and abs(x) <= _FLOAT32_MAX):
        raise CGVQMError(f"{path}: {name} is {_shown(value)}; it must be a finite number "
                         "(within float32's range)")
    return x


def _json_omega(path: Path, value: Any) -> np.ndarray:
    """omega as the format defines it: one flat array of N numbers, N = 131 or 1027.

    Checked entry by entry so that nothing numpy would coerce passes: a list of lists of
    the right total size, strings that parse as numbers, booleans, NaN or overflowing values.
    """
    sizes = " or ".join(f"{v.n_channels} ({v.name.upper()})" for v in VARIANTS.values())
    shape = f"omega must be a flat JSON array of {sizes} numbers"
    if not isinstance(value, list):
        raise CGVQMError(f"{path}: {shape}, not {_a(value)}")
    for i, x in enumerate(value):
        if isinstance(x, list | dict):
            raise CGVQMError(f"{path}: {shape}; omega[{i}] is a nested {_json_type(x)} "
                             f"({_shown(x)})")
        _json_number(path, f"omega[{i}]", x)
    variant_for_channels(len(value), path)
    return np.asarray(value, dtype=np.float32)



def save_weights(path: str | Path, weights: FeatureWeights) -> Path:
    """Write weights in the project format (``cgvqm-weights/1`` JSON); returns the path.

    Keys: ``format``, ``variant``, ``n_levels``, ``alpha``, ``omega`` (list of N numbers in
    level order input, stem, layer1, ...; signs kept, the metric uses |omega|) and
    ``provenance`` (free dict: datasets, split, seed, correlations, backbone sha256...).
    """
    path = Path(path)
    doc = {
        "format": PROJECT_FORMAT,
        "variant": weights.variant,
        "n_levels": weights.n_levels,
        "alpha": float(weights.alpha),
        "omega": [float(x) for x in np.asarray(weights.omega, dtype=np.float32)],
        "provenance": weights.provenance,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def load_project_weights(path: str | Path) -> FeatureWeights:
    """Read a ``cgvqm-weights/1`` JSON file."""
    path = Path(path)
    data = _read(path)
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CGVQMError(f"{path}: not a readable weights JSON file ({exc})") from None
    fmt = str(doc.get("format", "")) if isinstance(doc, dict) else ""
    name, _, major = fmt.partition("/")
    if name != "cgvqm-weights":
        raise CGVQMError(f"{path}: not a CGVQM weights file (format {fmt!r})")
    if major != "1":
        raise CGVQMError(f"{path}: weights format {fmt!r} is not supported (this version "
                         f"reads {PROJECT_FORMAT!r}); upgrade the toolkit")
    missing = [k for k in ("omega", "alpha") if k not in doc]
    if missing:
        raise CGVQMError(f"{path}: weights file lacks {' and '.join(missing)}")
    if "anchoring" in doc:  # read only under provenance: refused rather than ignored
        raise CGVQMError(f"{path}: 'anchoring' at the top level is not read; the score "
                         "anchoring (cgvqm-anchor/1) belongs under 'provenance' "
                         "(provenance.anchoring): move it there")
    omega = _json_omega(path, doc["omega"])
    alpha = _json_number(path, "alpha", doc["alpha"])
    variant = variant_for_channels(omega.size, path)
    if doc.get("variant") not in (None, variant.name):
        raise CGVQMError(f"{path}: says variant {_shown(doc['variant'])} but omega has "
                         f"{omega.size} entries ({variant.name})")
    if doc.get("n_levels") not in (None, variant.n_levels) or isinstance(doc.get("n_levels"),
                                                                          bool):
        raise CGVQMError(f"{path}: says n_levels {_shown(doc['n_levels'])} but omega has "
                         f"{omega.size} entries ({variant.name}: {variant.n_levels} levels)")
    _check_values(path, omega, alpha)
    provenance = doc.get("provenance") or {}
    if not isinstance(provenance, dict):
        raise CGVQMError(f"{path}: 'provenance' must be a JSON object (keys such as datasets, "
                         f"split, seed), not a {type(provenance).__name__}")
    return FeatureWeights(variant.name, omega, alpha, sha256_bytes(data), str(path), "project",
                          dict(provenance))


def load_weights(path: str | Path, *, expected_sha256: str | None = None) -> FeatureWeights:
    """Load either format, told apart by content (JSON object or pickle stream)."""
    path = Path(path)
    head = _read(path)[:1]
    if head == b"{":
        return load_project_weights(path)
    if head == b"\x80":
        return load_upstream_pickle(path, expected_sha256=expected_sha256)
    raise CGVQMError(f"{path}: neither a CGVQM weights pickle nor a cgvqm-weights JSON file")


def uniform_weights(variant: str) -> FeatureWeights:
    """omega = 1/N, alpha = 1: for smoke tests and demos without the published weights."""
    v = VARIANTS[variant]
    log.warning("using UNIFORM feature weights: scores are not CGVQM scores")
    omega = np.full(v.n_channels, 1.0 / v.n_channels, dtype=np.float32)
    return FeatureWeights(variant, omega, 1.0, "uniform", "uniform", "uniform",
                          {"note": "uniform weights, not a calibrated metric"})


# -- fetching and caching ----------------------------------------------------------------------


def cache_dir() -> Path:
    """Where fetched weights live: $CGVQM_CACHE, else ~/.cache/cgvqm."""
    env = os.environ.get("CGVQM_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "cgvqm"


def offline() -> bool:
    """True when $CGVQM_OFFLINE is set to a true value: never try the network."""
    return os.environ.get("CGVQM_OFFLINE", "").strip().lower() in ("1", "true", "yes", "on")


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise CGVQMError(f"{path}: no such weights file") from None
    except OSError as exc:
        raise CGVQMError(f"{path}: cannot read ({exc})") from None


def candidates(variant: Variant) -> list[Path]:
    out = [cache_dir() / variant.file_name]
    extra = os.environ.get("CGVQM_WEIGHTS_DIR")
    if extra:
        out.append(Path(extra).expanduser() / variant.file_name)
    return out


def fetch_upstream(variant: str, *, source_dir: str | Path | None = None,
                   force: bool = False) -> Path:
    """Put the published pickle of ``variant`` into the cache (sha256-checked); return its path.

    ``source_dir`` copies it from a local folder instead of downloading.
    """
    v = _variant(variant)
    target = cache_dir() / v.file_name
    if target.is_file() and not force and sha256_bytes(target.read_bytes()) == v.sha256:
        return target
    if source_dir is not None:
        src = Path(source_dir) / v.file_name
        data = _read(src)
        origin = str(src)
    else:
        if offline():
            raise CGVQMError(missing_message(v, "CGVQM_OFFLINE is set"))
        url = UPSTREAM_URL.format(name=v.file_name)
        log.info("downloading %s", url)
        try:
            with urllib.request.urlopen(url, timeout=60) as resp:
                data = resp.read()
        except OSError as exc:
            raise CGVQMError(missing_message(v, f"download failed: {exc}")) from None
        origin = url
    digest = sha256_bytes(data)
    if digest != v.sha256:
        raise CGVQMError(f"{origin}: sha256 {digest} does not match the published "
                         f"{v.file_name} ({v.sha256}); refusing to use it")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=target.parent, delete=False) as fh:
        fh.write(data)
    shutil.move(fh.name, target)
    return target


def _variant(name: str) -> Variant:
    try:
        return VARIANTS[name]
    except KeyError:
        raise CGVQMError(f"unknown variant {name!r}; choose {' or '.join(VARIANTS)}") from None


def missing_message(v: Variant, why: str) -> str:
    return (
        f"the published {v.name} weights ({v.file_name}) are not available ({why}); "
        f"run `cgvqm weights fetch` online, or `cgvqm weights fetch --from DIR` with a folder "
        f"holding {v.file_name}, or pass --weights PATH (or set CGVQM_WEIGHTS_DIR)"
    )


def published_weights(variant: str, *, allow_download: bool = True) -> FeatureWeights:
    """The authors' weights of ``variant``: from the cache or $CGVQM_WEIGHTS_DIR, else fetched."""
    v = _variant(variant)
    for path in candidates(v):
        if path.is_file():
            return load_upstream_pickle(path, expected_sha256=v.sha256)
    if not allow_download:
        raise CGVQMError(missing_message(v, "not in the cache"))
    return load_upstream_pickle(fetch_upstream(variant), expected_sha256=v.sha256)


def resolve_weights(spec: str | Path | FeatureWeights | None, variant: str = "cgvqm-2", *,
                    allow_download: bool = True) -> FeatureWeights:
    """Weights from a variant's published file, a path (either format), or 'uniform'."""
    if isinstance(spec, FeatureWeights):
        return spec
    if spec is None:
        return published_weights(variant, allow_download=allow_download)
    if str(spec) == "uniform":
        return uniform_weights(_variant(variant).name)
    path = Path(spec)
    expected = next((v.sha256 for v in VARIANTS.values() if v.file_name == path.name), None)
    return load_weights(path, expected_sha256=expected)
