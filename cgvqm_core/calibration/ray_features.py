"""``cgvqm calibrate --ray``: the calibration's feature jobs as Ray tasks.

One task per reference with all of its test videos, as in a local run; the workers read the
videos from storage all nodes see at the same paths and check their content first. The feature
cache still writes every entry here, on the driver, as each reference comes back. The cluster
machinery (connecting, resources, retries, failure reasons) is :mod:`cgvqm_core.distributed`'s.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import ray
import ray.exceptions

from stimuli_manifests import sha256_path

from ..batch import canonical_json
from ..distributed import (
    as_completed,
    as_task,
    check_resources,
    failure_reason,
    finished_by,
    reuse_in_worker,
    start_task,
)
from ..errors import CGVQMError
from ..ray_options import RaySettings
from .cache import _folder_hash
from .pipeline import FeatureSource, metric_features

log = logging.getLogger(__name__)


# -- the worker side ------------------------------------------------------------------------

def _source(feature_args: dict[str, Any]) -> Any:
    return reuse_in_worker(canonical_json(["features", feature_args]),
                           lambda: metric_features(**feature_args))


def _feature_settings_task(feature_args: dict[str, Any], cpus: int) -> dict[str, Any]:
    start_task("", cpus)
    s = _source(feature_args)
    return {"settings": s.settings, "backbone": s.backbone, "supersets": s.supersets}


def _features_task(job: dict[str, Any], feature_args: dict[str, Any], group_size: int,
                   cpus: int) -> dict[str, Any]:
    """m of one reference's test videos, computed ``group_size`` at a time as locally."""
    start = start_task(job["label"], cpus)
    _verify_content([(job["reference"], job["reference_sha256"]),
                     *zip(job["tests"], job["test_sha256"], strict=True)])
    compute = _source(feature_args).compute
    tests, step = list(job["tests"]), max(1, group_size)
    arrays = [m for s in range(0, len(tests), step)
              for m in compute(job["reference"], tests[s: s + step])]
    return {"arrays": arrays, **finished_by(start)}


def _verify_content(files: Sequence[tuple[str, str]]) -> None:
    """The feature cache keys files by content: refuse a file that is not that content."""
    for path, sha in files:
        p = Path(path)
        if not p.exists():
            raise CGVQMError(f"{path}: not found on this node ({ray.util.get_node_ip_address()}"
                             "); every node must see the videos at the same paths")
        if sha256_path(p) != sha and not (p.is_dir() and _folder_hash(p) == sha):
            raise CGVQMError(f"{path} on node {ray.util.get_node_ip_address()} is not the "
                             f"file the driver hashed (sha256 {sha[:12]}...); every node must "
                             "see the same files")


# -- the driver side ------------------------------------------------------------------------

def feature_source(feature_args: dict[str, Any], settings: RaySettings, *,
                   group_size: int = 4) -> FeatureSource:
    """A calibration ``FeatureSource`` whose jobs (one per reference) run as Ray tasks.

    ``feature_args`` are :func:`~cgvqm_core.calibration.pipeline.metric_features`'s keyword
    arguments; the cache's settings come from a worker (which has the backbone). The cache
    still writes every entry, here, as each reference comes back. Needs a connected Ray
    (:func:`cgvqm_core.distributed.connected`).
    """
    check_resources(settings)
    try:
        info = ray.get(as_task(_feature_settings_task, settings).remote(
            feature_args, settings.cpus_per_unit))
    except ray.exceptions.RayError as exc:
        raise CGVQMError(f"--ray: a worker could not build the metric's network: "
                         f"{failure_reason(exc, settings)}") from None

    def compute(ref: str, tests: Sequence[str]) -> list[Any]:
        raise CGVQMError("features of this source are computed by Ray tasks (its runner)")

    def runner(jobs: Sequence[Any]) -> Iterator[tuple[int, list[Any]]]:
        task = as_task(_features_task, settings)
        pending = {task.remote(_job_dict(j), feature_args, group_size,
                               settings.cpus_per_unit): i for i, j in enumerate(jobs)}
        failed = []
        for i, result, why in as_completed(pending, settings):
            if why is not None:
                failed.append(f"{jobs[i].label}: {why}")
                log.info("features of %s failed: %s", jobs[i].label, why)
                continue
            assert result is not None
            yield i, result["arrays"]
        if failed:
            raise CGVQMError(f"{len(failed)} of {len(jobs)} reference(s) failed on Ray (the "
                             "others' features are cached; rerun to retry): "
                             + "; ".join(failed))

    return FeatureSource(compute, info["settings"], info["backbone"], info["supersets"],
                         runner=runner)


def _job_dict(job: Any) -> dict[str, Any]:
    return {"label": job.label, "reference": os.path.abspath(job.reference),
            "reference_sha256": job.reference_sha256,
            "tests": [os.path.abspath(t) for t in job.tests],
            "test_sha256": list(job.test_sha256)}
