"""Where the R3D-18 backbone's parameters come from, and proof of which ones were used.

In order: an explicit file (``--backbone PATH``), ``$CGVQM_BACKBONE``, torchvision's Kinetics-400
checkpoint in the torch hub cache, a download of that checkpoint (hash-checked by torch.hub)
unless ``$CGVQM_OFFLINE`` is set. A seeded random backbone exists only behind an explicit
argument and is labelled ``random-seed-N`` in every output.
"""

from __future__ import annotations

import hashlib
import logging
import operator
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from .backbone import build_backbone, expected_keys
from .errors import CGVQMError, key_mismatch
from .safe_load import load_tensors, refusal_reason
from .weights import offline

log = logging.getLogger(__name__)

BACKBONE_FILE = "r3d_18-b3b3357e.pth"
BACKBONE_URL = "https://download.pytorch.org/models/r3d_18-b3b3357e.pth"
BACKBONE_ENV = "CGVQM_BACKBONE"
#: torch.hub checks that the file's sha256 starts with the 8 hex digits in its name
HASH_PREFIX = "b3b3357e"


@dataclass
class Backbone:
    """A state dict in torchvision's key layout plus its provenance."""

    state_dict: dict[str, torch.Tensor]
    sha256: str
    source: str
    label: str  # file name, or "random-seed-N"
    arch: str = "r3d_18"
    random_seed: int | None = None

    @property
    def is_random(self) -> bool:
        return self.random_seed is not None


def hub_checkpoint_path() -> Path:
    """Where torch.hub keeps the downloaded checkpoint."""
    return Path(torch.hub.get_dir()) / "checkpoints" / BACKBONE_FILE


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def offline_message(why: str) -> str:
    return (
        f"the R3D-18 backbone ({BACKBONE_FILE}, torchvision's Kinetics-400 weights) is not "
        f"available ({why}); copy the file to {hub_checkpoint_path()}, or pass --backbone PATH "
        f"(or set {BACKBONE_ENV}=PATH), or run `cgvqm weights fetch` where the network is "
        "reachable; --random-backbone SEED gives a random network for testing only"
    )


def check_state_dict(sd: Mapping[str, torch.Tensor], arch: str, origin: str) -> None:
    """Refuse anything that is not a complete state dict of ``arch`` (names and shapes)."""
    want = expected_keys(arch)
    have = set(sd)
    optional = {k for k in want if k.endswith("num_batches_tracked")}
    missing = sorted(set(want) - have - optional)
    unexpected = sorted(have - set(want))
    if missing or unexpected:
        raise CGVQMError(f"{origin}: not a torchvision {arch} state dict: "
                         + key_mismatch(missing, unexpected))
    for k, shape in want.items():
        if k in sd and tuple(sd[k].shape) != shape:
            raise CGVQMError(f"{origin}: {k} has shape {tuple(sd[k].shape)}, expected {shape}")


def load_backbone_file(path: str | Path, arch: str = "r3d_18") -> Backbone:
    """Read a state dict file (tensors only; no code is executed) and check its keys."""
    path = Path(path).expanduser()
    if path.is_dir():
        raise CGVQMError(f"{path}: is a folder; give the backbone's state dict file "
                         f"({BACKBONE_FILE})")
    if not path.is_file():
        raise CGVQMError(f"{path}: no such backbone file; {offline_message('file missing')}")
    if path.stat().st_size == 0:
        raise CGVQMError(f"{path}: the backbone file is empty (an interrupted copy?); copy "
                         f"{BACKBONE_FILE} again")
    try:
        sd = load_tensors(path)
    except Exception as exc:  # torch raises many types for refused or broken files
        raise CGVQMError(f"{path}: not a readable PyTorch state dict ({refusal_reason(exc)}); "
                         f"give the R3D-18 file {BACKBONE_FILE}") from None
    if isinstance(sd, Mapping) and "state_dict" in sd and isinstance(sd["state_dict"], Mapping):
        sd = sd["state_dict"]
    if not isinstance(sd, Mapping):
        raise CGVQMError(f"{path}: holds a {type(sd).__name__}, not a state dict")
    check_state_dict(sd, arch, str(path))
    digest = sha256_file(path)
    if path.name == BACKBONE_FILE and not digest.startswith(HASH_PREFIX):
        raise CGVQMError(f"{path}: sha256 {digest} does not start with {HASH_PREFIX} as "
                         "the file name promises; the file is corrupt, download it again")
    if arch == "r3d_18" and not digest.startswith(HASH_PREFIX):
        log.warning("%s: not torchvision's Kinetics-400 R3D-18 file (sha256 %s...); its "
                    "scores are not the published metric's (the backbone_sha256 column "
                    "says which file made them)", path, digest[:12])
    return Backbone(dict(sd), digest, str(path), path.name, arch)


def state_dict_sha256(sd: Mapping[str, torch.Tensor]) -> str:
    """A hash of a state dict's names and tensor bytes (for backbones that have no file)."""
    h = hashlib.sha256()
    for k in sorted(sd):
        t = sd[k].detach().cpu().contiguous()
        h.update(k.encode())
        h.update(str(t.dtype).encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


#: the seeds torch.manual_seed takes without wrapping: it also accepts -2**63..-1, but maps
#: a negative seed s to 2**64 + s, so -1 and 18446744073709551615 would be one network
#: under two labels
MAX_SEED = 2**64 - 1


def check_seed(seed: int, what: str = "random backbone seed") -> int:
    """``seed`` if it is an integer in 0..2**64-1; a :class:`CGVQMError` naming it otherwise."""
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)
    except TypeError:
        value = None
    if value is None or not 0 <= value <= MAX_SEED:
        raise CGVQMError(f"{what} must be an integer from 0 to {MAX_SEED} (2**64 - 1, the "
                         f"range torch.manual_seed takes without wrapping), got {seed!r}")
    return value


def random_backbone(seed: int, arch: str = "r3d_18") -> Backbone:
    """A seeded torchvision-style random initialisation, labelled as such."""
    seed = check_seed(seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        sd = build_backbone(arch).state_dict()
    log.warning("using a RANDOM backbone (seed %d): scores are not CGVQM scores", seed)
    return Backbone(sd, state_dict_sha256(sd), f"random seed {seed}", f"random-seed-{seed}",
                    arch, random_seed=int(seed))


def from_state_dict(sd: Mapping[str, torch.Tensor], arch: str = "r3d_18",
                    label: str = "state-dict") -> Backbone:
    """Wrap an in-memory state dict (checked like a file)."""
    check_state_dict(sd, arch, label)
    return Backbone(dict(sd), state_dict_sha256(sd), label, label, arch)


def fetch_backbone(*, source: str | Path | None = None) -> Path:
    """Put the Kinetics-400 checkpoint into the torch hub cache; return its path.

    ``source`` copies a local file there (after checking it); otherwise torch.hub downloads
    it with its hash check.
    """
    target = hub_checkpoint_path()
    if source is not None:
        bb = load_backbone_file(source)
        if not bb.sha256.startswith(HASH_PREFIX):
            raise CGVQMError(f"{source}: sha256 {bb.sha256} is not the one of {BACKBONE_FILE}")
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".part")
        tmp.write_bytes(Path(source).read_bytes())
        tmp.replace(target)
        return target
    if target.is_file():
        return target
    if offline():
        raise CGVQMError(offline_message("CGVQM_OFFLINE is set"))
    try:
        torch.hub.load_state_dict_from_url(BACKBONE_URL, map_location="cpu", check_hash=True,
                                           weights_only=True)
    except RuntimeError as exc:  # torch.hub's hash mismatch
        raise CGVQMError(f"downloaded backbone failed its hash check ({exc})") from None
    except OSError as exc:
        raise CGVQMError(offline_message(f"download failed: {exc}")) from None
    return target


def resolve_backbone(spec: str | Path | Backbone | Mapping[str, torch.Tensor] | None = None, *,
                     random_seed: int | None = None, allow_download: bool = True,
                     arch: str = "r3d_18") -> Backbone:
    """Find the backbone the user asked for (see module docstring for the order)."""
    if isinstance(spec, Backbone):
        return spec
    if random_seed is not None:
        if spec is not None:
            raise CGVQMError("give either a backbone file or a random seed, not both")
        return random_backbone(random_seed, arch)
    if isinstance(spec, Mapping):
        return from_state_dict(spec, arch)
    if spec is None and os.environ.get(BACKBONE_ENV):
        spec = os.environ[BACKBONE_ENV]
    if spec is not None:
        return load_backbone_file(spec, arch)
    if arch != "r3d_18":
        raise CGVQMError(f"no published CGVQM backbone for {arch}; pass --backbone PATH")
    path = hub_checkpoint_path()
    if not path.is_file():
        if not allow_download:
            raise CGVQMError(offline_message("not in the torch hub cache"))
        path = fetch_backbone()
    return load_backbone_file(path, arch)
