"""Where a batch's tasks run: a LocalCluster on 127.0.0.1 (the default) or a running Dask
cluster given by its scheduler's address; and what each run asks of a worker.

A run on a GPU asks for `GPU` (--gpus-per-run, default 1), a run on the CPU for `CPU` cores
(--cores-per-run). The local cluster's workers offer those resources; a remote cluster's workers
must be started with them (`dask worker ADDRESS --nthreads 1 --resources CPU=16`, or GPU=1 on a
GPU machine), else no task could ever be placed and the batch says so at once.
"""

from __future__ import annotations

import glob
import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass, field

from splat_core.errors import InputError

CORES_PER_RUN_DEFAULT = 4       # a CPU run's threads when the machine has more cores than that
MEMORY_PER_RUN_GB = 3.0         # a cpu-preset run on a 640x480 capture peaks near 2 GB (README, long_run)
ALLOWED_FAILURES = 3            # worker deaths a task survives (Dask retries it on another worker)
WAIT_FOR_WORKERS_SECONDS = 60


def require_dask() -> None:
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError(install_hint()) from None


def install_hint() -> str:
    from app.console_commands import pip_install

    return f"splatam batch needs Dask: {pip_install('splatam-viewer[batch]')}"


def machine_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def available_memory_gb() -> float:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    import psutil    # a dependency of distributed
    return psutil.virtual_memory().available / 2**30


def local_gpus() -> list[str]:
    """The GPU ids this machine offers (CUDA_VISIBLE_DEVICES when set), without importing torch."""
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is not None:
        return [g for g in visible.split(",") if g.strip() and g.strip() != "-1"]
    return sorted((p[len("/dev/nvidia"):] for p in glob.glob("/dev/nvidia[0-9]*")), key=int)


@dataclass
class Layout:
    """How runs are placed: resources a task asks for, and (local cluster) the workers to start."""
    task_resources: dict
    workers: int = 0
    worker_resources: dict = field(default_factory=dict)
    cores_per_run: int | None = None
    gpu_slots: dict = field(default_factory=dict)     # worker name -> CUDA_VISIBLE_DEVICES

    def describe(self) -> str:
        what = ", ".join(f"{k}={v:g}" for k, v in self.task_resources.items())
        return f"each run asks for {what}"


def local_layout(device: str, workers: int | None, cores_per_run: int | None, gpus_per_run: int | None) -> Layout:
    """Workers and resources of a local cluster: one worker per run slot."""
    for flag, value in (("--workers", workers), ("--cores-per-run", cores_per_run), ("--gpus-per-run", gpus_per_run)):
        if value is not None and value < (0 if flag == "--gpus-per-run" else 1):
            raise InputError(f"{flag} {value}: expected a positive number")
    cores = machine_cores()
    gpus = local_gpus() if device != "cpu" else []
    if gpus_per_run or (gpus_per_run is None and gpus and device in ("auto", "cuda")):
        per = gpus_per_run or 1
        if len(gpus) < per:
            raise InputError(f"--gpus-per-run {per}: this machine offers {len(gpus)} GPU(s)")
        n = workers or len(gpus) // per
        slots = {i: ",".join(gpus[(i * per) % len(gpus):][:per]) for i in range(n)}
        c = cores_per_run or max(1, cores // n)
        return Layout({"GPU": per}, n, {"GPU": per, "CPU": c}, c, slots)
    if device == "cuda":
        raise InputError("--device cuda: no NVIDIA GPU found on this machine (/dev/nvidia*)")
    if workers is None:
        per = cores_per_run or min(cores, CORES_PER_RUN_DEFAULT)
        workers = max(1, min(cores // per, int(available_memory_gb() // MEMORY_PER_RUN_GB)))
    c = cores_per_run or max(1, cores // workers)
    return Layout({"CPU": c}, workers, {"CPU": c}, c)


def remote_layout(client, device: str, cores_per_run: int | None, gpus_per_run: int | None) -> Layout:
    """Resources a task asks of a running cluster; InputError when no worker offers them."""
    workers = client.scheduler_info().get("workers", {})
    if not workers:
        try:
            client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_SECONDS)
        except Exception:
            raise InputError(f"{client.scheduler.address}: no worker joined within {WAIT_FOR_WORKERS_SECONDS} s "
                             "(start some: dask worker ADDRESS --nthreads 1 --resources CPU=N)") from None
        workers = client.scheduler_info().get("workers", {})
    gpu = bool(gpus_per_run) or device == "cuda"
    key = "GPU" if gpu else "CPU"
    offered = [w.get("resources", {}).get(key, 0) for w in workers.values()]
    if gpu:
        amount = gpus_per_run or 1
    else:   # default: the smallest worker's cores, so every worker can take a run
        amount = cores_per_run or min((v for v in offered if v > 0), default=1)
    if not any(v >= amount for v in offered):
        raise InputError(f"{client.scheduler.address}: no worker offers the resource {key}={amount:g} that each run "
                         f"asks for (start workers with: dask worker ADDRESS --nthreads 1 --resources {key}=N)")
    return Layout({key: amount}, cores_per_run=None if gpu else int(amount))


def _ignore_sigint_plugin_class():
    from distributed import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        def setup(self, worker):
            import signal
            import threading
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)
    return IgnoreSigint


def _IgnoreSigint():
    return _ignore_sigint_plugin_class()()


@contextmanager
def open_client(scheduler: str | None, layout_args: dict):
    """(client, layout, description lines) for a running cluster or a new local one on loopback."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({e})") from None
        try:
            layout = remote_layout(client, **layout_args)
            n = len(client.scheduler_info().get("workers", {}))
            yield client, layout, [f"cluster: {scheduler} ({n} workers now); {layout.describe()}"]
        finally:
            client.close()
        return
    layout = local_layout(**layout_args)
    dashboard = None
    try:
        import bokeh  # noqa: F401   (the dashboard needs it)
        dashboard = "127.0.0.1:0"
    except ImportError:
        pass
    # The workers only wait on their runs' processes: no statistical profiler sampling them.
    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
                          "distributed.worker.profile.enabled": False}):
        cluster = LocalCluster(n_workers=layout.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=dashboard, silence_logs=logging.CRITICAL,
                               resources=layout.worker_resources, memory_limit=0)
    client = Client(cluster)
    try:
        # Ctrl-C in the terminal reaches every process of the group: the runs stop themselves
        # (exit 130, checkpoints kept) and this process closes the cluster; the workers need not
        # each print a KeyboardInterrupt traceback.
        client.register_plugin(_IgnoreSigint(), name="splatam-ignore-sigint")
        lines = [f"cluster: local on {cluster.scheduler_address}, {layout.workers} worker(s); {layout.describe()}"]
        if dashboard:
            lines.append(f"dashboard: {client.dashboard_link}")
        yield client, layout, lines
    finally:
        client.close(timeout=10)
        cluster.close(timeout=10)
