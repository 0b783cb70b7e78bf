"""The Ray plumbing of the distributed runs: connect, submit one task per shard or scene with bounded resources and
retries, show progress on the driver, collect results in submission order.

    with ray_session("auto" | "local" | "HOST:PORT" | "ray://HOST:PORT"):
        results = run_tasks(fn, [args, ...], TaskResources(cpus=1, memory_gb=1.0, retries=3), desc="dataset")

`ray` is imported here, inside functions only: a run without `--ray` never imports it. Tasks are plain functions
of `worldsplat.scale.*`; the cluster's workers import them, so every node needs the same `worldsplat` installed and
the output folder on storage they all see (web/docs/scale-out.md).
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from tqdm import tqdm


class RayStartTimeout(RuntimeError):
    """A local Ray instance could not start (its node missed Ray's start-up deadline every time)."""


class TaskFailures(RuntimeError):
    """Some tasks failed after their retries; what finished is on disk and a re-run does only the rest."""


@dataclass(frozen=True)
class TaskResources:
    """What one task asks the scheduler for: `cpus` cores (also its render/torch threads), `memory_gb` of RAM
    (scheduling, not a hard limit), and how often it is retried (a worker that dies, or an OSError)."""

    cpus: float = 1.0
    memory_gb: float = 1.0
    retries: int = 3

    def __post_init__(self) -> None:
        if not self.cpus > 0 or not self.memory_gb > 0 or self.retries < 0:
            raise ValueError("--ray-cpus and --ray-memory-gb must be positive and --ray-retries at least 0")

    @property
    def threads(self) -> int:
        return max(1, int(self.cpus))


def add_ray_arguments(p) -> None:
    """The options every distributed command shares."""
    p.add_argument(
        "--ray",
        nargs="?",
        const="auto",
        default=None,
        metavar="auto|local|ADDRESS",
        help="run as Ray tasks: auto = the running cluster (`ray start` / RAY_ADDRESS), local = a private one on "
        "this machine, or HOST:PORT / ray://HOST:PORT",
    )
    p.add_argument("--ray-cpus", type=float, default=1.0, help="cores per task (also its threads; default 1)")
    p.add_argument("--ray-memory-gb", type=float, default=1.0, help="memory per task for scheduling (default 1)")
    p.add_argument("--ray-retries", type=int, default=3, help="retries of a task whose worker died (default 3)")


def resources_from_args(args) -> TaskResources:
    return TaskResources(args.ray_cpus, args.ray_memory_gb, args.ray_retries)


def check_reachable(address: str, timeout_s: float = 3.0) -> None:
    """A clear error for an address nothing listens on (Ray itself would retry for a long while)."""
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--ray: expected auto, local, HOST:PORT or ray://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise ValueError(f"--ray: cannot reach a Ray cluster at {address} ({e.strerror or e})") from None


def start_local(num_cpus: int | None = None, tries: int = 3) -> None:
    """A private Ray instance on this machine, tried again when its node times out starting: on a machine loaded
    several times over its cores, Ray 2.60's raylet gives up on its dashboard agent (a Python process) before that
    is up, and the driver then reports "timed out during startup" (RayStartTimeout after `tries`)."""
    import ray  # noqa: PLC0415 - heavy optional dependency: only a --ray run imports it

    for i in range(tries):
        try:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
            return
        except Exception as e:  # Ray raises a bare Exception for the start-up time-out
            if "timed out during startup" not in str(e):
                raise
            ray.shutdown()
            if i + 1 == tries:
                raise RayStartTimeout(f"Ray did not start in {tries} tries: {e}") from None


@contextlib.contextmanager
def ray_session(address: str) -> Iterator[None]:
    """Connected to Ray for the duration; a Ray already initialised by the caller is used as it is and left up."""
    import ray  # noqa: PLC0415 - heavy optional dependency: only a --ray run imports it

    if ray.is_initialized():
        yield
        return
    if address == "local":
        try:
            start_local()
        except RayStartTimeout as e:
            raise ValueError(f"--ray local: {e}") from None
    else:
        if address != "auto":
            check_reachable(address)
        try:
            ray.init(address=address, log_to_driver=False)
        except ConnectionError as e:
            hint = " (start one with `ray start --head`, or use --ray local)" if address == "auto" else ""
            raise ValueError(f"--ray {address}: no Ray cluster to connect to{hint}: {e}") from None
    try:
        yield
    finally:
        ray.shutdown()


def _check_feasible(res: TaskResources) -> None:
    """A task no node can hold would wait forever: say so instead."""
    import ray  # noqa: PLC0415 - heavy optional dependency: only a --ray run imports it

    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    need_mem = res.memory_gb * 2**30
    if nodes and not any(r.get("CPU", 0) >= res.cpus and r.get("memory", need_mem) >= need_mem for r in nodes):
        best = max(nodes, key=lambda r: r.get("CPU", 0))
        raise ValueError(
            f"a task asks for {res.cpus:g} CPU and {res.memory_gb:g} GiB, but the largest node of this Ray cluster "
            f"has {best.get('CPU', 0):g} CPU and {best.get('memory', 0) / 2**30:.1f} GiB: lower --ray-cpus / "
            "--ray-memory-gb"
        )


def run_tasks(
    fn: Callable, arg_lists: list[tuple], res: TaskResources, desc: str, unit: str = "task", progress: bool = True
) -> list:
    """Run `fn(*args)` for every args tuple as a Ray task; results in the order given. Every task is waited for
    (finished work stays finished); then TaskFailures names the ones that failed after their retries."""
    import ray  # noqa: PLC0415 - heavy optional dependency: only a --ray run imports it

    if not arg_lists:
        return []
    _check_feasible(res)
    remote = ray.remote(fn).options(
        num_cpus=res.cpus,
        memory=int(res.memory_gb * 2**30),
        max_retries=res.retries,
        retry_exceptions=[OSError],
    )
    pending = {remote.remote(*args): i for i, args in enumerate(arg_lists)}
    results: list = [None] * len(arg_lists)
    failures: list[str] = []
    with tqdm(total=len(arg_lists), desc=desc, unit=unit, disable=not progress) as bar:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                i = pending.pop(ref)
                try:
                    results[i] = ray.get(ref)
                except (ray.exceptions.RayTaskError, ray.exceptions.RayError) as e:
                    cause = getattr(e, "cause", None) or e
                    first = (str(cause).splitlines() or [""])[0]
                    failures.append(f"{desc} task {i}: {type(cause).__name__}: {first}")
                bar.update()
    if failures:
        raise TaskFailures(f"{len(failures)} of {len(arg_lists)} task(s) failed: " + "; ".join(failures[:5]))
    return results
