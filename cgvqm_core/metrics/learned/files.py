"""The learned metrics' weight files: found locally, hash-checked, read safely; never fetched.

Each metric needs one or two files ("parts"): a feature network (torchvision's ImageNet
VGG-16 or AlexNet) and its learned head (LPIPS's linear layers, DISTS's alpha/beta), or a
whole network (PieAPP). A part's file is looked for, in order:

1. ``--learned-weights PART=PATH`` (``MetricOptions.learned_weights``);
2. ``$CGVQM_<PART>_WEIGHTS`` (e.g. ``CGVQM_VGG16_WEIGHTS``, ``CGVQM_LPIPS_ALEX_WEIGHTS``);
3. folders given as ``--learned-weights DIR`` or in ``$CGVQM_LEARNED_WEIGHTS_DIR``
   (``os.pathsep``-separated), under the part's published file names;
4. the torch hub cache (``$TORCH_HOME/hub/checkpoints``), where torchvision and PIQ keep the
   files they downloaded, under the names they use;
5. a copy shipped inside an installed package (``lpips``, ``torchmetrics``,
   ``DISTS_pytorch``), used only when its sha256 is the published one.

Every file is hashed (sha256). A hash the user states (``--learned-sha256 PART=HEX`` or
``$CGVQM_<PART>_SHA256``) must match; a torchvision file name, which carries the first
digits of its hash, must be the published file; any other file is used and recorded as
"not a published file" when its hash is not a published one. Files are read with
``torch.load(weights_only=True)``, PyTorch's allow-list unpickler: tensors and plain
containers only, no code runs. Nothing here opens a network connection.
"""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...errors import CGVQMError, key_mismatch
from ...safe_load import load_tensors, refusal_reason

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)

DIR_ENV = "CGVQM_LEARNED_WEIGHTS_DIR"


@dataclass(frozen=True)
class Part:
    """One weights file a learned metric needs, and what is known of its published form."""

    name: str
    title: str
    names: tuple[str, ...]  # file names looked for in folders (published names)
    hub_names: tuple[str, ...]  # names torchvision / PIQ give it in the torch hub cache
    published: tuple[tuple[str, str], ...]  # (sha256, which published file)
    licence: str
    fmt: str  # what the file holds
    bundled: tuple[tuple[str, str], ...] = ()  # (package, path inside it)
    hash_in_name: bool = False  # torchvision: names[0] holds the sha256's first 8 digits

    @property
    def env(self) -> str:
        return f"CGVQM_{self.name.upper().replace('-', '_')}_WEIGHTS"

    @property
    def sha_env(self) -> str:
        return f"CGVQM_{self.name.upper().replace('-', '_')}_SHA256"

    def published_as(self, sha256: str) -> str | None:
        return dict(self.published).get(sha256)


TV_LICENCE = ("torchvision's ImageNet weights, distributed with torchvision under BSD-3-Clause "
              "(trained on ImageNet-1k: its terms of access apply)")

PARTS: dict[str, Part] = {p.name: p for p in (
    Part("vgg16", "VGG-16 ImageNet weights (torchvision)", ("vgg16-397923af.pth",),
         ("vgg16-397923af.pth",),
         (("397923af8e79cdbb6a7127f12361acd7a2f83e06b05044ddf496e83de57a5bf0",
           "torchvision vgg16-397923af.pth (VGG16_Weights.IMAGENET1K_V1)"),),
         TV_LICENCE, "torchvision VGG-16 state dict (complete, or features.* only)",
         hash_in_name=True),
    Part("alexnet", "AlexNet ImageNet weights (torchvision)", ("alexnet-owt-7be5be79.pth",),
         ("alexnet-owt-7be5be79.pth",),
         (("7be5be791159472b1fbf3c69796f7cb30dca7ad8466c2df70058c37116cdee02",
           "torchvision alexnet-owt-7be5be79.pth (AlexNet_Weights.IMAGENET1K_V1)"),),
         TV_LICENCE, "torchvision AlexNet state dict (complete, or features.* only)",
         hash_in_name=True),
    Part("lpips", "LPIPS v0.1 linear heads for VGG-16", ("vgg.pth", "lpips_weights.pt"),
         ("lpips_weights.pt",),
         (("a78928a0af1e5f0fcb1f3b9e8f8c3a2a5a3de244d830ad5c1feddc79b8432868",
           "LPIPS v0.1 weights/v0.1/vgg.pth (richzhang/PerceptualSimilarity)"),),
         "BSD-2-Clause (Zhang et al., LPIPS)",
         "LPIPS state dict lin0..lin4.model.1.weight, or PIQ's list of five tensors",
         bundled=(("lpips", "weights/v0.1/vgg.pth"),
                  ("torchmetrics", "functional/image/lpips_models/vgg.pth"))),
    Part("lpips-alex", "LPIPS v0.1 linear heads for AlexNet", ("alex.pth",), (),
         (("df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0",
           "LPIPS v0.1 weights/v0.1/alex.pth (richzhang/PerceptualSimilarity)"),),
         "BSD-2-Clause (Zhang et al., LPIPS)", "LPIPS state dict lin0..lin4.model.1.weight",
         bundled=(("lpips", "weights/v0.1/alex.pth"),
                  ("torchmetrics", "functional/image/lpips_models/alex.pth"))),
    Part("dists", "DISTS alpha/beta weights", ("weights.pt", "dists_weights.pt"),
         ("dists_weights.pt",),
         (("f5e65c96230b7f6ca995691647d482237e4cab8a50c5c4a5784f219ef0748218",
           "DISTS DISTS_pytorch/weights.pt (dingkeyan93/DISTS)"),),
         "MIT (Ding et al., DISTS)", "dict {'alpha', 'beta'} of 1475 numbers each",
         bundled=(("DISTS_pytorch", "weights.pt"),
                  ("torchmetrics", "functional/image/dists_models/weights.pt"))),
    Part("pieapp", "PieAPP v0.1 network", ("PieAPPv0.1.pth",), ("PieAPPv0.1.pth",),
         (("0937b01480c7a637ae3018af755faa8ecde4788b52bb246b7ae62cf96fb6baf0",
           "PieAPPv0.1.pth as re-published by PIQ (release v0.5.4)"),),
         "the PieAPP authors' (Prashnani et al.); their repository states no licence: "
         "research use as they distribute it", "PieAPP v0.1 PyTorch state dict"),
)}


@dataclass(frozen=True)
class WeightsFile:
    """A located, hashed and safely loaded weights file."""

    part: Part
    path: Path
    sha256: str
    published: str | None  # which published file it is, or None
    origin: str
    content: Any

    def describe(self) -> dict[str, Any]:
        return {"file": self.path.name, "sha256": self.sha256,
                "published": self.published or "no (not a published file)"}


def _dirs(options_dirs: tuple[str, ...] | list[str]) -> list[tuple[Path, str]]:
    out = [(Path(d).expanduser(), "--learned-weights folder") for d in options_dirs]
    env = os.environ.get(DIR_ENV, "")
    out += [(Path(d).expanduser(), f"${DIR_ENV}") for d in env.split(os.pathsep) if d]
    return out


def hub_checkpoints() -> Path:
    """Where torchvision and PIQ keep what they download ($TORCH_HOME/hub/checkpoints)."""
    import torch

    return Path(torch.hub.get_dir()) / "checkpoints"


def sha256_file(path: Path) -> str:
    from ...hub import sha256_file as digest  # imports torch: only when a file is there

    return digest(path)


def _bundled(part: Part) -> Path | None:
    """A copy an installed package ships, if its sha256 is the published one."""
    for package, rel in part.bundled:
        try:
            spec = importlib.util.find_spec(package)  # finds, does not import
        except (ImportError, ValueError):
            spec = None
        if spec is None:
            continue
        roots = list(spec.submodule_search_locations or [])
        for root in roots:
            p = Path(root) / rel
            if p.is_file() and part.published_as(sha256_file(p)):
                return p
    return None


def locate(part_name: str, explicit: Mapping[str, str] | None = None,
           dirs: tuple[str, ...] | list[str] = ()) -> tuple[Path, str] | None:
    """(path, where it came from) of a part's file, or None. An explicitly named file that
    does not exist is an error (it never falls through to another file)."""
    part = PARTS[part_name]
    given = [((explicit or {}).get(part.name), f"--learned-weights {part.name}="),
             (os.environ.get(part.env), f"${part.env}")]
    for value, origin in given:
        if value:
            p = Path(value).expanduser()
            if not p.is_file():
                raise CGVQMError(f"{p}: no such file ({part.title}, from {origin}); "
                                 "nothing is downloaded")
            return p, origin
    for d, origin in _dirs(dirs):
        for name in part.names:
            if (d / name).is_file():
                return d / name, f"{origin} {d}"
    hub = hub_checkpoints()
    for name in part.hub_names:
        if (hub / name).is_file():
            return hub / name, "torch hub cache"
    p = _bundled(part)
    return (p, "installed package copy") if p else None


def how_to_give(part: Part) -> str:
    return (f"{part.title} ({' or '.join(part.names)}): --learned-weights {part.name}=PATH, "
            f"${part.env}, or a folder holding it (--learned-weights DIR, ${DIR_ENV})")


def _expected(part: Part, stated: Mapping[str, str] | None) -> str | None:
    value = (stated or {}).get(part.name) or os.environ.get(part.sha_env)
    if not value:
        return None
    value = value.strip().lower()
    if len(value) != 64 or any(c not in "0123456789abcdef" for c in value):
        raise CGVQMError(f"expected sha256 for {part.name} must be 64 hex digits, got {value!r}")
    return value


def _read(path: Path) -> Any:
    try:
        return load_tensors(path)
    except Exception as exc:  # torch raises many types for refused or broken files
        raise CGVQMError(f"{path}: not a weights file PyTorch's safe loader accepts "
                         f"({refusal_reason(exc)})") from None


def load(part_name: str, explicit: Mapping[str, str] | None = None,
         dirs: tuple[str, ...] | list[str] = (),
         stated_sha256: Mapping[str, str] | None = None) -> WeightsFile:
    """Locate, hash-check and read one part's file (see the module docstring)."""
    part = PARTS[part_name]
    found = locate(part_name, explicit, dirs)
    if found is None:
        raise CGVQMError(f"no local file for {how_to_give(part)}; nothing is downloaded")
    path, origin = found
    digest = sha256_file(path)
    expected = _expected(part, stated_sha256)
    if expected is not None and digest != expected:
        raise CGVQMError(f"{path}: sha256 {digest} is not the expected {expected} "
                         f"({part.title}); the file is corrupt or not the one you meant")
    published = part.published_as(digest)
    if part.hash_in_name and path.name == part.names[0] and published is None:
        raise CGVQMError(f"{path}: sha256 {digest} is not that of the published "
                         f"{path.name} ({part.published[0][0]}); the file is corrupt or "
                         "incomplete, copy it again")
    content = _read(path)  # a file that cannot be read is an error, and only that
    if published is None and expected is None:
        log.warning("%s: sha256 %s is not that of a published %s file; its scores are "
                    "recorded as from unpublished weights", path, digest, part.title)
    if isinstance(content, Mapping) and isinstance(content.get("state_dict"), Mapping):
        content = content["state_dict"]
    return WeightsFile(part, path, digest, published, origin, content)


# -- what the files must hold ----------------------------------------------------------------


def _tensor(obj: Any, origin: str, what: str) -> torch.Tensor:
    import torch

    if not isinstance(obj, torch.Tensor):
        raise CGVQMError(f"{origin}: {what} is a {type(obj).__name__}, not a tensor")
    if not torch.isfinite(obj).all():
        raise CGVQMError(f"{origin}: {what} holds non-finite numbers")
    return obj


def features_state(f: WeightsFile, full: Mapping[str, tuple[int, ...]]) -> dict[str, Any]:
    """The ``features`` part of a torchvision state dict, keyed as ``features`` itself keys
    it ("0.weight", ...). Accepts the complete torchvision dict, its ``features.*`` entries,
    or ``features``' own state dict; anything else (a missing, extra or misshapen entry) is
    refused with the names."""
    import torch

    sd = f.content
    origin = str(f.path)
    if not isinstance(sd, Mapping):
        raise CGVQMError(f"{origin}: holds a {type(sd).__name__}, not a {f.part.fmt}")
    feat = {k: s for k, s in full.items() if k.startswith("features.")}
    if sd and all(not k.startswith(("features.", "classifier.")) for k in sd):
        sd = {f"features.{k}": v for k, v in sd.items()}  # features' own state dict
    keys = set(sd)
    wanted = set(full) if keys - set(feat) else set(feat)  # a complete dict must be complete
    missing = sorted(wanted - keys)
    unexpected = sorted(keys - set(full))
    if missing or unexpected:
        raise CGVQMError(f"{origin}: not a {f.part.fmt}: " + key_mismatch(missing, unexpected))
    for k in keys:
        t = sd[k]
        if not isinstance(t, torch.Tensor) or tuple(t.shape) != full[k]:
            shape = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
            raise CGVQMError(f"{origin}: {k} has shape {shape}, expected {full[k]}")
    out = {k[len("features."):]: _tensor(sd[k], origin, k).float() for k in feat}
    return out


def lpips_heads(f: WeightsFile, channels: tuple[int, ...]) -> list[torch.Tensor]:
    """Five per-channel weight vectors from an LPIPS state dict or PIQ's list."""
    obj = f.content
    origin = str(f.path)
    if isinstance(obj, Mapping):
        keys = [f"lin{k}.model.1.weight" for k in range(len(channels))]
        extra = sorted(set(obj) - set(keys))
        if any(k not in obj for k in keys) or extra:
            raise CGVQMError(f"{origin}: not a {f.part.fmt} (keys {', '.join(sorted(obj))})")
        heads = [obj[k] for k in keys]
    elif isinstance(obj, list | tuple):
        heads = list(obj)
    else:
        raise CGVQMError(f"{origin}: holds a {type(obj).__name__}, not a {f.part.fmt}")
    if len(heads) != len(channels):
        raise CGVQMError(f"{origin}: {len(heads)} heads, LPIPS needs {len(channels)}")
    out = []
    for k, (h, c) in enumerate(zip(heads, channels, strict=True)):
        h = _tensor(h, origin, f"head {k}")
        if h.numel() != c:
            raise CGVQMError(f"{origin}: head {k} has {h.numel()} weights, expected {c}")
        out.append(h.reshape(-1).float())
    return out


def dists_alpha_beta(f: WeightsFile, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    obj = f.content
    origin = str(f.path)
    if not (isinstance(obj, Mapping) and set(obj) >= {"alpha", "beta"}):
        raise CGVQMError(f"{origin}: not a {f.part.fmt}")
    out = []
    for key in ("alpha", "beta"):
        t = _tensor(obj[key], origin, key)
        if t.numel() != n:
            raise CGVQMError(f"{origin}: {key} has {t.numel()} numbers, expected {n}")
        out.append(t.reshape(-1).float())
    total = float(out[0].sum() + out[1].sum())
    if abs(total - 1) > 1e-3:
        log.warning("%s: alpha and beta sum to %.6g, not 1: identical images will not score "
                    "0 (PIQ uses them as stored)", origin, total)
    return out[0], out[1]


def pieapp_state(f: WeightsFile, full: Mapping[str, tuple[int, ...]]) -> dict[str, Any]:
    sd = f.content
    origin = str(f.path)
    if not isinstance(sd, Mapping):
        raise CGVQMError(f"{origin}: holds a {type(sd).__name__}, not a {f.part.fmt}")
    import torch

    sd = dict(sd)
    w = sd.get("ref_score_subtract.weight")
    if isinstance(w, torch.Tensor) and tuple(w.shape) == (1,):
        sd["ref_score_subtract.weight"] = w.reshape(1, 1)  # the published file stores (1,)
    missing = sorted(set(full) - set(sd))
    unexpected = sorted(set(sd) - set(full))
    if missing or unexpected:
        raise CGVQMError(f"{origin}: not a {f.part.fmt} (missing {missing[:3]}, unexpected "
                         f"{unexpected[:3]})")
    for k, shape in full.items():
        t = _tensor(sd[k], origin, k)
        if tuple(t.shape) != shape:
            raise CGVQMError(f"{origin}: {k} has shape {tuple(t.shape)}, expected {shape}")
    return {k: sd[k].float() for k in full}
