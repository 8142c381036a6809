"""The ``--ray`` options of ``cgvqm batch`` and ``cgvqm calibrate`` (Ray only with ``--ray``).

Ray is an optional extra (``[cluster]``): these options are parsed and checked here, and the
modules that import Ray (:mod:`cgvqm_core.distributed`,
:mod:`cgvqm_core.calibration.ray_features`) are imported by the commands only when ``--ray``
is given, after :func:`require_ray`, so that a missing Ray is one line naming the extra
rather than a failure of every command.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from stimuli_manifests.extras import explain_missing

from .errors import CGVQMError

#: ``--ray`` without an address: start a Ray instance on this machine
LOCAL = "local"


@dataclass(frozen=True)
class RaySettings:
    """Where the work units run and what each one asks the cluster for."""

    address: str = LOCAL  # LOCAL, "auto" (the cluster this node belongs to) or HOST:PORT
    cpus_per_unit: int = 1  # also the unit's torch threads
    gpus_per_unit: float = 0.0  # 0 on CPU; 1 (or a fraction to share a GPU) with cuda
    max_retries: int = 3  # tries after a worker dies (a crash, an out-of-memory kill)


def add_ray_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("many machines (Ray; needs the [cluster] extra)")
    g.add_argument("--ray", nargs="?", const=LOCAL, metavar="ADDRESS",
                   help="run one reference (with all its test videos) per Ray task: without "
                        "ADDRESS on a Ray instance started here; 'auto' or HOST:PORT joins a "
                        "running cluster (`ray start --head`). Every node must see the videos "
                        "at the same paths; this machine writes the results")
    g.add_argument("--ray-cpus-per-unit", type=int, metavar="N",
                   help="CPUs each task reserves, and its PyTorch threads (default 1)")
    g.add_argument("--ray-gpus-per-unit", type=float, metavar="G",
                   help="GPUs each task reserves with --device cuda (default 1; a fraction "
                        "such as 0.5 puts two tasks on one GPU)")
    g.add_argument("--ray-retries", type=int, metavar="N",
                   help="times a task is rerun after its worker died (default 3)")


def ray_settings(args: argparse.Namespace, device: str) -> RaySettings | None:
    """The checked settings, or None without ``--ray``; with ``--ray``, Ray must be installed
    (:func:`require_ray`)."""
    given = [flag for flag, value in (("--ray-cpus-per-unit", args.ray_cpus_per_unit),
                                      ("--ray-gpus-per-unit", args.ray_gpus_per_unit),
                                      ("--ray-retries", args.ray_retries)) if value is not None]
    if args.ray is None:
        if given:
            raise CGVQMError(f"{given[0]} needs --ray")
        return None
    if getattr(args, "threads", None) is not None:
        raise CGVQMError("--threads with --ray: each task runs --ray-cpus-per-unit PyTorch "
                         "threads; give that instead")
    cpus = 1 if args.ray_cpus_per_unit is None else args.ray_cpus_per_unit
    retries = 3 if args.ray_retries is None else args.ray_retries
    address = args.ray.strip()
    if not address:
        raise CGVQMError("--ray ADDRESS is empty; give 'auto', HOST:PORT, or no address")
    if cpus < 1:
        raise CGVQMError(f"--ray-cpus-per-unit must be at least 1, got {cpus}")
    if retries < 0:
        raise CGVQMError(f"--ray-retries must be 0 or more, got {retries}")
    kind, _, index = device.partition(":")
    if kind == "cuda":
        if index:
            raise CGVQMError(f"with --ray give --device cuda, not {device}: Ray gives each "
                             "task its GPU(s)")
        gpus = 1.0 if args.ray_gpus_per_unit is None else args.ray_gpus_per_unit
        if gpus <= 0:
            raise CGVQMError(f"--ray-gpus-per-unit must be above 0 with --device cuda, "
                             f"got {gpus:g}")
    else:
        if args.ray_gpus_per_unit is not None:
            raise CGVQMError("--ray-gpus-per-unit needs --device cuda")
        gpus = 0.0
    require_ray()
    return RaySettings(address, cpus, gpus, retries)


def require_ray() -> None:
    """Refuse ``--ray`` without Ray installed, in one line naming the ``[cluster]`` extra (before
    any work, rather than when the first task would start)."""
    try:
        import ray  # noqa: F401
    except ModuleNotFoundError as exc:
        missing = explain_missing(exc, what="--ray")
        if missing is None:
            raise
        raise missing from None
