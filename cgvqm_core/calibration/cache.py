"""The feature cache: per video, per patch, per channel mean squared feature differences.

Fitting omega touches only these numbers (``m`` of shape (patches, N) per video), never the
videos, so they are computed once by the backbone and kept on disk: one ``.npy`` file per
(test video, reference video) pair in a folder named after everything that changes them
(variant, backbone sha256, patch scale, precision), plus a small JSON index that says what
each file is. Entries are written atomically (temporary file, then rename) as soon as they
are computed, so an interrupted run loses at most the videos in flight and a rerun computes
only what is missing. Video identity is the content (sha256), so a moved dataset still hits.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from stimuli_manifests import sha256_file

from ..errors import CGVQMError

log = logging.getLogger(__name__)

CACHE_FORMAT = "cgvqm-feature-cache/1"

#: computes m for several test videos sharing one reference: (ref, tests) -> [(P_i, N)]
FeatureFn = Callable[[str, Sequence[str]], list[np.ndarray]]


@dataclass(frozen=True)
class FeatureJob:
    """Test videos sharing one reference, with the content sha256s their cache keys use (so
    that a worker on another machine can check it reads the same files)."""

    label: str  # the reference's id (or path), for messages
    reference: str
    reference_sha256: str
    tests: tuple[str, ...]
    test_sha256: tuple[str, ...]


#: runs jobs anywhere, in any order, yielding (job index, m per test) as each one finishes;
#: the cache stays the only writer of its entries and index (see FeatureCache.build)
JobRunner = Callable[[Sequence[FeatureJob]], Iterable[tuple[int, list[np.ndarray]]]]


def _atomic_write(path: Path, write: Callable[[Any], None], mode: str = "wb") -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class FeatureCache:
    """One cache folder for one feature setting (``settings`` must hold the variant,
    ``n_channels`` and ``backbone_sha256``; every key in it is part of the folder name)."""

    def __init__(self, root: str | Path, settings: dict[str, Any],
                 supersets: Sequence[FeatureCache] = ()) -> None:
        for key in ("variant", "n_channels", "backbone_sha256"):
            if key not in settings:
                raise CGVQMError(f"feature cache settings lack {key!r}")
        self.settings = dict(settings)
        digest = hashlib.sha256(json.dumps(self.settings, sort_keys=True).encode()).hexdigest()
        self.folder = Path(root) / f"{settings['variant']}-{digest[:16]}"
        self.n_channels = int(settings["n_channels"])
        self._index_path = self.folder / "index.json"
        self._hashes: dict[str, str] = {}
        # caches whose entries start with this one's columns (CGVQM-5 holds CGVQM-2's first
        # 131: input, stem, layer1): entries found there are sliced instead of recomputed
        self.supersets = [c for c in supersets if c.n_channels > self.n_channels]

    # -- keys ---------------------------------------------------------------------------
    def video_hash(self, path: str, known: str | None = None) -> str:
        """Content sha256 of a video file (the manifest's when it has one)."""
        if isinstance(known, str) and known:
            return known
        if path not in self._hashes:
            p = Path(path)
            if not p.exists():
                raise CGVQMError(f"{path}: video not found (check the manifest's root)")
            self._hashes[path] = sha256_file(p) if p.is_file() else _folder_hash(p)
        return self._hashes[path]

    def key(self, test_sha: str, ref_sha: str) -> str:
        return hashlib.sha256(f"{test_sha}|{ref_sha}".encode()).hexdigest()[:32]

    def entry_path(self, key: str) -> Path:
        return self.folder / f"{key}.npy"

    # -- index --------------------------------------------------------------------------
    def read_index(self) -> dict[str, Any]:
        if not self._index_path.is_file():
            return {"format": CACHE_FORMAT, "settings": self.settings, "entries": {}}
        try:
            doc = json.loads(self._index_path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            log.warning("%s is unreadable; it is rebuilt from the entries", self._index_path)
            return {"format": CACHE_FORMAT, "settings": self.settings, "entries": {}}
        if doc.get("format") != CACHE_FORMAT:
            raise CGVQMError(f"{self._index_path}: cache format {doc.get('format')!r} is not "
                             f"{CACHE_FORMAT!r}; use another --cache folder")
        return doc

    def _write_index(self, doc: dict[str, Any]) -> None:
        data = (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode()
        _atomic_write(self._index_path, lambda fh: fh.write(data))

    # -- entries ------------------------------------------------------------------------
    def load_entry(self, key: str) -> np.ndarray | None:
        """The cached (P, N) array, or None when absent or unreadable (then recomputed)."""
        path = self.entry_path(key)
        if not path.is_file():
            return None
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            log.warning("cache entry %s is unreadable (%s); recomputing it", path, exc)
            return None
        if arr.ndim != 2 or arr.shape[1] != self.n_channels or arr.shape[0] < 1:
            log.warning("cache entry %s has shape %s; recomputing it", path, arr.shape)
            return None
        return arr

    def save_entry(self, key: str, m: np.ndarray) -> None:
        m = np.ascontiguousarray(m, dtype=np.float32)
        if m.ndim != 2 or m.shape[1] != self.n_channels:
            raise CGVQMError(f"feature function returned shape {m.shape}; expected "
                             f"(patches, {self.n_channels})")
        if not np.all(np.isfinite(m)) or (m < 0).any():
            raise CGVQMError("feature function returned negative or non-finite mean squared "
                             "differences")
        _atomic_write(self.entry_path(key), lambda fh: np.save(fh, m, allow_pickle=False))

    def build(self, items: pd.DataFrame, compute: FeatureFn, *, group_size: int = 4,
              show_progress: bool = True, runner: JobRunner | None = None
              ) -> list[np.ndarray]:
        """m for every row of ``items`` (columns test_path, ref_path; optional test_sha256,
        ref_sha256, stimulus, reference, dataset), computing only what the cache lacks.

        Test videos sharing a reference are computed together (``group_size`` at a time), so
        the reference goes through the backbone once per group. With a ``runner`` (e.g. Ray
        tasks) each reference is one job and the runner computes it where it likes; entries
        are still written here, as each job comes back.
        """
        self.folder.mkdir(parents=True, exist_ok=True)
        doc = self.read_index()
        keys: list[str] = []
        shas: list[tuple[str, str]] = []
        hashing = tqdm(total=len(items), desc="hashing videos", unit="video",
                       disable=not show_progress, leave=False)
        for row in items.itertuples(index=False):
            t = self.video_hash(row.test_path, getattr(row, "test_sha256", None))
            r = self.video_hash(row.ref_path, getattr(row, "ref_sha256", None))
            keys.append(self.key(t, r))
            shas.append((t, r))
            hashing.update()
        hashing.close()
        out: list[np.ndarray | None] = [self.load_entry(k) for k in keys]
        for i, k in enumerate(keys):
            for sup in self.supersets if out[i] is None else ():
                m = sup.load_entry(k)
                if m is not None:
                    self.save_entry(k, m[:, : self.n_channels])
                    out[i] = self.load_entry(k)
                    break
        todo = [i for i, m in enumerate(out) if m is None]
        # the same pair listed twice is computed once
        first: dict[str, int] = {}
        for i in todo:
            first.setdefault(keys[i], i)
        pending = sorted(first.values())
        log.info("feature cache %s: %d of %d videos cached, %d to compute", self.folder,
                 len(items) - len(todo), len(items), len(pending))
        by_ref: dict[str, list[int]] = {}
        for i in pending:
            by_ref.setdefault(str(items.iloc[i]["ref_path"]), []).append(i)
        step = max(1, group_size)
        chunks: list[list[int]] = []
        for idx in by_ref.values():
            if runner is not None:
                chunks.append(idx)  # one job per reference; the runner groups its tests
            else:
                chunks += [idx[s: s + step] for s in range(0, len(idx), step)]
        jobs = [self._job(items, chunk, shas) for chunk in chunks]
        results = (runner(jobs) if runner is not None else
                   ((j, compute(job.reference, list(job.tests))) for j, job in enumerate(jobs)))
        bar = tqdm(total=len(pending), desc="features", unit="video",
                   disable=not show_progress or not pending)
        try:
            for j, ms in results:
                self._store(doc, items, keys, chunks[j], ms)
                bar.update(len(chunks[j]))
        finally:
            bar.close()
        for i in todo:
            out[i] = self.load_entry(keys[i])
            if out[i] is None:
                raise CGVQMError(f"feature cache entry for {items.iloc[i]['test_path']} could "
                                 f"not be read back from {self.folder}")
        return out  # type: ignore[return-value]

    @staticmethod
    def _job(items: pd.DataFrame, chunk: list[int], shas: list[tuple[str, str]]
             ) -> FeatureJob:
        row = items.iloc[chunk[0]]
        ref = str(row["ref_path"])
        label = "/".join(str(row.get(c, "") or "") for c in ("dataset", "reference")
                         if row.get(c, "")) or ref
        return FeatureJob(label, ref, shas[chunk[0]][1],
                          tuple(str(items.iloc[i]["test_path"]) for i in chunk),
                          tuple(shas[i][0] for i in chunk))

    def _store(self, doc: dict[str, Any], items: pd.DataFrame, keys: list[str],
               chunk: list[int], ms: list[np.ndarray]) -> None:
        """Write one job's entries, then the index (so an interruption loses no entry)."""
        if len(ms) != len(chunk):
            raise CGVQMError(f"feature function returned {len(ms)} arrays for "
                             f"{len(chunk)} videos")
        for i, m in zip(chunk, ms, strict=True):
            self.save_entry(keys[i], m)
            row = items.iloc[i]
            doc["entries"][keys[i]] = {
                "file": self.entry_path(keys[i]).name,
                "stimulus": str(row.get("stimulus", "")),
                "dataset": str(row.get("dataset", "")),
                "test": str(row["test_path"]), "reference": str(row["ref_path"]),
                "n_patches": int(np.shape(m)[0]),
            }
        self._write_index(doc)


def _folder_hash(folder: Path) -> str:
    """Hash of an image-sequence folder: names and contents of its files, in order."""
    h = hashlib.sha256()
    for p in sorted(folder.iterdir()):
        if p.is_file():
            h.update(p.name.encode())
            h.update(sha256_file(p).encode())
    return h.hexdigest()


def pack(arrays: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Stack per-video (P_i, N) arrays into a zero-padded (V, max P, N) float32 array and the
    patch counts (zero rows never win the max: errors are >= 0)."""
    if not arrays:
        raise CGVQMError("no videos to calibrate on")
    n = {a.shape[1] for a in arrays}
    if len(n) != 1:
        raise CGVQMError(f"videos have different channel counts {sorted(n)}")
    counts = np.array([a.shape[0] for a in arrays])
    M = np.zeros((len(arrays), int(counts.max()), n.pop()), dtype=np.float32)
    for i, a in enumerate(arrays):
        M[i, : a.shape[0]] = a
    return M, counts
