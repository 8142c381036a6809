"""Work units on a Ray cluster: ``cgvqm batch --ray`` and ``cgvqm calibrate --ray``.

One Ray task per reference with all of its test videos (its features are computed once), as
in a local run. Tasks carry paths and sha256s only, never decoded frames: every node reads
the videos itself from storage all nodes see at the same paths, and checks their sha256
first, so a node with other files fails loudly instead of scoring them. Results come back to
the driver (this process), which is the only writer: score rows go through the scores CSV's
``Appender`` and feature arrays through ``FeatureCache``, as each task finishes (on Ray a
unit's rows come back together when its task ends, not per group of tests as in a local
run: an interrupted driver loses the units in flight). A dead driver
therefore resumes from its CSV or cache like a local run; a dead worker costs its task, which
Ray reruns (``max_retries``); a task that fails on every try is reported by name while the
others still land.

Numbers are those of a local run: the same code scores the same unit, with as many torch
threads as CPUs the task reserves (bitwise equal for equal device, precision and threads).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import ray
import ray.exceptions

from stimuli_manifests.cli_runner import one_line
from stimuli_manifests.errors import ToolkitError

from .batch import (
    Appender,
    BatchSummary,
    WorkUnit,
    canonical_json,
    done_keys,
    manifest_units,
    planned_rows,
    read_scores,
    refuse_clashes,
    refuse_misaligned_pairs,
    run_unit,
    scorer_plan,
    scores_lock,
    unit_keys,
)
from .errors import CGVQMError
from .metrics.registry import MetricOptions, build_scorers
from .progress import Progress, progress_bar
from .ray_options import LOCAL, RaySettings

log = logging.getLogger(__name__)

#: test-only: a JSON file {unit label: marker path}; the first try at that unit (while the
#: marker does not exist) kills its own worker with SIGKILL, as a crash would
FAULTS_ENV = "CGVQM_TEST_FAULTS"

T = TypeVar("T")


# -- the cluster ----------------------------------------------------------------------------

@contextmanager
def connected(settings: RaySettings) -> Iterator[None]:
    """Ray for the duration: a local instance, or the cluster at ``settings.address``.

    A Ray already initialised in this process (a notebook, a test) is used as it is and left
    running; otherwise the connection is closed (a local instance stopped) at the end.
    """
    if ray.is_initialized():
        yield
        return
    _check_reachable(settings.address)
    try:
        if settings.address == LOCAL:
            ray.init(address="local", include_dashboard=False, logging_level=logging.WARNING)
        else:
            ray.init(address=settings.address, logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        if settings.address == LOCAL:
            raise CGVQMError(f"--ray: could not start a local Ray instance "
                             f"({_first_line(exc)})") from None
        raise CGVQMError(f"--ray: could not join the Ray cluster at {settings.address} "
                         f"({_first_line(exc)}); start it with `ray start --head` on its head "
                         "node; a cluster with token authentication also needs "
                         "RAY_AUTH_MODE=token and its token (~/.ray/auth_token) here") from None
    try:
        yield
    finally:
        ray.shutdown()


def _check_reachable(address: str) -> None:
    """A HOST:PORT where nothing listens is one line now, not minutes of Ray's retries."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if address in (LOCAL, "auto") or not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5).close()
    except OSError as exc:
        raise CGVQMError(f"--ray {address}: nothing answers there ({exc.strerror or exc}); "
                         "is `ray start --head` running on that node, and is the port open "
                         "from here?") from None


def check_resources(settings: RaySettings) -> int:
    """Refuse a request no node can satisfy (its tasks would wait forever); return how many
    tasks the cluster can run at once."""
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    fits = [r for r in nodes if r.get("CPU", 0) >= settings.cpus_per_unit
            and r.get("GPU", 0) >= settings.gpus_per_unit]
    if not fits:
        best_cpu = max((r.get("CPU", 0) for r in nodes), default=0)
        best_gpu = max((r.get("GPU", 0) for r in nodes), default=0)
        raise CGVQMError(f"--ray: no node of the cluster has {settings.cpus_per_unit:g} CPU(s) "
                         f"and {settings.gpus_per_unit:g} GPU(s) for a task (the largest has "
                         f"{best_cpu:g} CPUs, {best_gpu:g} GPUs); lower --ray-cpus-per-unit "
                         "or --ray-gpus-per-unit, or add nodes")
    per_node = []
    for r in fits:
        n = r.get("CPU", 0) // settings.cpus_per_unit
        if settings.gpus_per_unit:
            n = min(n, r.get("GPU", 0) // settings.gpus_per_unit)
        per_node.append(int(n))
    return sum(per_node)


def as_task(fn: Callable[..., Any], settings: RaySettings) -> Any:
    """``fn`` as a Ray task with the unit's resources; errors raised by our code are not
    retried (they would fail again), a dead worker is (``max_retries``)."""
    return ray.remote(fn).options(
        num_cpus=settings.cpus_per_unit, num_gpus=settings.gpus_per_unit,
        max_retries=settings.max_retries, retry_exceptions=False)


# -- the worker side ------------------------------------------------------------------------

_BUILT: dict[str, Any] = {}  # the last scorers / feature source built in this worker process


def reuse_in_worker(key: str, build: Callable[[], T]) -> T:
    """Build once per worker process (a worker runs many units with the same settings)."""
    if key not in _BUILT:
        _BUILT.clear()
        _BUILT[key] = build()
    return _BUILT[key]


def start_task(label: str, cpus: int) -> float:
    import torch

    _test_fault(label)
    torch.set_num_threads(cpus)
    return time.perf_counter()


def _test_fault(label: str) -> None:
    spec = os.environ.get(FAULTS_ENV)
    if not spec:
        return
    try:
        marker = json.loads(Path(spec).read_text(encoding="utf-8")).get(label)
    except (OSError, ValueError):
        return
    if marker and not Path(marker).exists():
        Path(marker).write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)


def finished_by(start: float) -> dict[str, Any]:
    return {"seconds": time.perf_counter() - start, "node": ray.util.get_node_ip_address(),
            "pid": os.getpid()}


def _scorers(metrics: list[str], options: dict[str, Any]) -> list[Any]:
    from .batch import options_from_dict

    return reuse_in_worker(canonical_json(["scorers", metrics, options]),
                  lambda: build_scorers(metrics, options_from_dict(options)))


def _plan_task(metrics: list[str], options: dict[str, Any], cpus: int) -> list[Any]:
    """Identity and poolings of each scorer, as a worker builds them (the driver's keys)."""
    from .batch import options_from_dict

    start_task("", cpus)
    return scorer_plan(_scorers(metrics, options), options_from_dict(options))


def _unit_task(unit: dict[str, Any], done: list[str], cpus: int) -> dict[str, Any]:
    """Score one unit (inputs' sha256 checked here); its rows and how long it took."""
    start = start_task(unit["reference_id"], cpus)
    u = WorkUnit.from_dict(unit)
    rows = run_unit(u, scorers=_scorers(u.metrics, u.options), done=set(done), verify=True)
    return {"rows": rows, **finished_by(start)}


# -- the driver side ------------------------------------------------------------------------

@dataclass
class RaySummary(BatchSummary):
    """A batch summary plus what the cluster did."""

    units: int = 0  # work units in the manifest
    submitted: int = 0  # units sent to Ray (the others were complete in the CSV)
    failed: list[str] = field(default_factory=list)  # "SRC02: why", one per failed unit
    unit_seconds: dict[str, float] = field(default_factory=dict)  # measured inside the task
    nodes: set[str] = field(default_factory=set)  # addresses of the nodes that ran units

    def failure_message(self, out: str | Path) -> str:
        return (f"{len(self.failed)} of {self.submitted} work unit(s) failed on Ray (the "
                f"others are in {out}; rerun to retry the failed ones): "
                + "; ".join(self.failed))


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return one_line(text.splitlines()[0] if text else type(exc).__name__)


def failure_reason(exc: BaseException, settings: RaySettings) -> str:
    """One line on why a task failed: our error's message, or how its worker died."""
    if isinstance(exc, ray.exceptions.RayTaskError):
        cause = getattr(exc, "cause", None)
        if isinstance(cause, ToolkitError):
            return one_line(cause)
        if cause is not None:
            return f"{type(cause).__name__}: {_first_line(cause)}"
    if isinstance(exc, ray.exceptions.WorkerCrashedError | ray.exceptions.NodeDiedError
                  | ray.exceptions.OutOfMemoryError):
        return (f"its worker died on each of {settings.max_retries + 1} tries "
                f"({type(exc).__name__}: {_first_line(exc)})")
    return f"{type(exc).__name__}: {_first_line(exc)}"


def as_completed(pending: dict[Any, T], settings: RaySettings
                 ) -> Iterator[tuple[T, dict[str, Any] | None, str | None]]:
    """(item, result, None) or (item, None, why it failed) for each task as it finishes."""
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            item = pending.pop(ref)
            try:
                result, why = ray.get(ref), None
            except ray.exceptions.RayError as exc:
                result, why = None, failure_reason(exc, settings)[:400]
            yield item, result, why


def _worker_plan(metrics: Sequence[str], options: MetricOptions, settings: RaySettings
                 ) -> list[Any]:
    """The scorers' identities as a worker sees them (the driver may lack the GPU, weights
    or backbone file the workers use), so keys here are the keys the workers write."""
    from .batch import options_to_dict

    task = as_task(_plan_task, settings)
    try:
        return ray.get(task.remote(list(metrics), options_to_dict(options),
                                   settings.cpus_per_unit))
    except ray.exceptions.RayError as exc:
        raise CGVQMError(f"--ray: a worker could not build the metrics: "
                         f"{failure_reason(exc, settings)}") from None


def score_units(units: Sequence[WorkUnit], out: str | Path, settings: RaySettings, *,
                progress: Progress = True) -> RaySummary:
    """Run the units whose rows are not all in ``out`` as Ray tasks; append rows as each
    finishes. Needs a connected Ray (:func:`connected`)."""
    with scores_lock(out):
        return _score_units(units, Path(out), settings, progress=progress)


def _score_units(units: Sequence[WorkUnit], out: Path, settings: RaySettings, *,
                 progress: Progress) -> RaySummary:
    state = read_scores(out)
    summary = RaySummary(units=len(units))
    if not units:
        return summary
    log.info("ray: %d task(s) at a time on this cluster", check_resources(settings))
    u0 = units[0]
    plan = _worker_plan(u0.metrics, _options(u0), settings)
    planned = planned_rows(units, plan)
    done = done_keys(state, planned)
    refuse_clashes(state, planned, "--out", done)
    task = as_task(_unit_task, settings)
    pending: dict[Any, tuple[WorkUnit, set[str]]] = {}
    skipped = 0
    for u in units:
        keys = set(unit_keys(u, plan))
        if keys <= done:
            skipped += len(u.tests)
            continue
        ref = task.remote(u.to_dict(), sorted(keys & done), settings.cpus_per_unit)
        pending[ref] = (u, keys)
    summary.submitted = len(pending)
    summary.skipped = skipped
    appender = Appender(out, state)
    bar = progress_bar(sum(len(u.tests) for u in units), "cgvqm batch (ray)", "video", progress,
                       initial=skipped)
    try:
        for (u, keys), result, why in as_completed(pending, settings):
            bar.update(len(u.tests))
            if result is not None and not {r["key"] for r in result["rows"]} <= keys:
                why = (f"node {result['node']} computed other resume keys than the first "
                       "worker (a different backbone, weights or torch version there); its "
                       "rows are not written")
            if why is not None:
                summary.failed.append(f"{u.reference_id}: {why}")
                log.info("work unit %s failed: %s", u.reference_id, why)
                continue
            assert result is not None
            rows = result["rows"]
            appender.write(rows)
            scored = {r["stimulus"] for r in rows}
            summary.scored += len(scored)
            summary.skipped += len(u.tests) - len(scored)
            summary.rows += len(rows)
            summary.unit_seconds[u.reference_id] = result["seconds"]
            summary.nodes.add(result["node"])
            for r in rows:
                done.add(r["key"])
                if r["note"] and not r["score"] and r["metric"] not in summary.not_applicable:
                    summary.not_applicable.append(r["metric"])
    finally:
        bar.close()
        appender.close()
    return summary


def _absolute(path: str | None) -> str | None:
    return os.path.abspath(path) if path and Path(path).exists() else path


def absolute_options(options: MetricOptions) -> MetricOptions:
    """The options with every local file (weights, backbone, learned weights) as an absolute
    path, so that workers, whose working folder differs, find the same files."""
    return replace(options, weights=_absolute(options.weights),
                   backbone=_absolute(options.backbone),
                   learned_weights={k: str(_absolute(v))
                                    for k, v in options.learned_weights.items()},
                   learned_dirs=tuple(str(_absolute(d)) for d in options.learned_dirs))


def _options(unit: WorkUnit) -> MetricOptions:
    from .batch import options_from_dict

    return options_from_dict(unit.options)


def score_manifest(manifest: str | Path, out: str | Path, metrics: Sequence[str],
                   options: MetricOptions, settings: RaySettings, *,
                   include_references: bool = False, root: str | Path | None = None,
                   group_size: int = 4, allow_resample: bool = False,
                   on_conversion: str = "warn", progress: Progress = True,
                   strict: bool = False) -> RaySummary:
    """:func:`cgvqm_core.batch.score_manifest` on Ray (same units, keys, rows and CSV)."""
    read_scores(Path(out))  # a folder or a file of another layout: refused before any work
    refuse_misaligned_pairs(manifest, include_references=include_references, root=root,
                            on_conversion=on_conversion, allow_resample=allow_resample,
                            strict=strict)
    units = manifest_units(manifest, metrics, absolute_options(options),
                           include_references=include_references, root=root,
                           group_size=group_size, allow_resample=allow_resample,
                           on_conversion=on_conversion, progress=progress, strict=strict)
    for u in units:  # a worker's working folder is not this one
        u.reference = replace(u.reference, path=os.path.abspath(u.reference.path))
        u.tests = [replace(t, path=os.path.abspath(t.path)) for t in u.tests]
    with connected(settings):
        return score_units(units, out, settings, progress=progress)
