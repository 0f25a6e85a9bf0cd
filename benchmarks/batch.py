"""`splatam batch` overheads and faults (issue 30); prints JSON.

    python benchmarks/batch.py                      # 8 captures of 10 frames, tiny settings (~10 min on 2 cores)
    python benchmarks/batch.py --captures 4 --frames 6

Measured in one invocation, on tiny synthetic TUM captures (tests/capture_fixtures.py, 64x48) with
a small config so that the fixed costs show:
- process_start_s: a fresh Python importing what `splatam run` imports (torch, the pipeline);
- cluster_start_s / cluster_close_s: a LocalCluster of 2 workers on 127.0.0.1 up (workers ready)
  and down;
- sequential: the captures one after another, `splatam run` each (a shell loop's cost);
- batch_1_worker: `splatam batch --workers 1` (the run gets all the cores) over the same captures,
  its wall time against the sequential total (target <= 1.05), and per capture the scheduler's
  share: the command's wall time less the cluster's start and the tasks' own wall time;
- batch_2_workers: `--workers 2 --cores-per-run 1` (two runs at once, one thread each);
- fault: a batch of 4 on 2 workers, one worker process killed (SIGKILL) after its run's first
  checkpoint: every capture must finish, the killed one resumed, each trajectory byte-identical
  to the sequential run of the same capture;
- scaling: the expected wall time of C captures on N machines of W runs each from the parts above.
Beside each wall time, the CPU time (user + system) of the command and every process under it:
on a machine shared with other jobs the wall times drift with their load, the CPU times much less.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from app.batch import state  # noqa: E402
from benchmarks.common import machine  # noqa: E402

TINY = """base: cpu
resolution: [64, 48]
checkpoint_every: 3
eval_every: 5
tracking: {iterations: 10}
mapping: {iterations: 6, first_frame_iterations: 20, window_size: 4}
"""


def env():
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))


def cpu_seconds() -> float:
    """CPU time (user + system) of this process's finished children and all they waited for: a
    batch's workers, its runs and its scheduler included. Unlike wall time it barely moves with
    the load that other jobs put on a shared machine."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


CPU = {"total": 0.0}


def timed(cmd) -> float:
    start, cpu = time.perf_counter(), cpu_seconds()
    subprocess.run(cmd, env=env(), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    CPU["last"] = cpu_seconds() - cpu
    return time.perf_counter() - start


def run_seconds(run_dir: Path) -> float:
    return sum(r["wall_seconds"] for r in state.read_metrics(run_dir)["per_frame"])


def cluster_start_close() -> tuple[float, float]:
    code = ("import time,logging;from distributed import LocalCluster,Client;t=time.perf_counter();"
            "c=LocalCluster(n_workers=2,threads_per_worker=1,host='127.0.0.1',dashboard_address=None,"
            "silence_logs=logging.CRITICAL);k=Client(c);k.wait_for_workers(2);a=time.perf_counter()-t;"
            "t=time.perf_counter();k.close();c.close();print(a,time.perf_counter()-t)")
    out = subprocess.run([sys.executable, "-c", code], env=env(), capture_output=True, text=True, check=True).stdout
    a, b = out.split()[-2:]
    return float(a), float(b)


def batch(caps, out: Path, config: Path, *extra) -> tuple[float, dict]:
    cmd = [sys.executable, "-m", "app.cli", "batch", *map(str, caps), "--out", str(out), "--config", str(config),
           "--quiet", *extra]
    start, cpu = time.perf_counter(), cpu_seconds()
    code = subprocess.run(cmd, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    wall = time.perf_counter() - start
    rows = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["captures"]}
    return wall, dict(exit_code=code, rows=rows, cpu_s=cpu_seconds() - cpu)


def fault_run(caps, out: Path, config: Path) -> dict:
    cmd = [sys.executable, "-m", "app.cli", "batch", *(c.path for c in caps), "--out", str(out), "--config",
           str(config), "--quiet", "--workers", "2", "--cores-per-run", "1"]
    proc = subprocess.Popen(cmd, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    killed, deadline = None, time.time() + 600
    while killed is None and time.time() < deadline and proc.poll() is None:
        for c in caps:
            d = out / c.name
            if state.has_checkpoint(d) and not (d / "metrics.json").exists():
                killed = c.name
                os.kill(state.read_status(d)["pid"], signal.SIGKILL)
                break
        time.sleep(0.05)
    code = proc.wait()
    rows = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["captures"]}
    return dict(exit_code=code, killed=killed, statuses={n: r["status"] for n, r in rows.items()},
                attempts={n: r["attempts"] for n, r in rows.items()})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=8)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--keep", default=None, help="work in this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    import capture_fixtures as fixtures

    work = Path(args.keep or tempfile.mkdtemp(prefix="splatam-batch-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    config = work / "tiny.yaml"
    config.write_text(TINY)
    caps = []
    for i in range(args.captures):
        fixtures.write_tum(work / "caps" / f"cap{i}", n=args.frames)
        caps.append(work / "caps" / f"cap{i}")
    from app.batch.captures import list_captures
    named = list_captures([str(c) for c in caps])
    run = [sys.executable, "-m", "app.cli", "run", "--config", str(config), "--quiet"]

    timed(run + ["--input", str(caps[0]), "--out", str(work / "warm")])         # compiles / loads Numba's cache
    starts, start_cpu = [], []
    for _ in range(3):
        starts.append(timed([sys.executable, "-c", "import app.commands.run, splat_core.run, torch"]))
        start_cpu.append(CPU["last"])
    cluster_start, cluster_close = cluster_start_close()

    def sequential(tag):
        walls, runs = [], []
        start, cpu = time.perf_counter(), cpu_seconds()
        for c in named:
            walls.append(timed(run + ["--input", c.path, "--out", str(work / tag / c.name)]))
            runs.append(run_seconds(work / tag / c.name))
        CPU[tag] = cpu_seconds() - cpu
        return time.perf_counter() - start, walls, runs

    # The machine is shared: the sequential runs go once before and once after the 1-worker batch,
    # and the batch is compared with their mean (the load drifts within minutes).
    seq_total_a, seq_walls, seq_runs = sequential("seq")
    b1_wall, b1 = batch(caps, work / "b1", config, "--workers", "1")
    seq_total_b, walls_b, _ = sequential("seq_again")
    seq_total = (seq_total_a + seq_total_b) / 2
    seq_walls += walls_b
    b2_wall, b2 = batch(caps, work / "b2", config, "--workers", "2", "--cores-per-run", "1")
    n = len(named)
    task_total = sum(r["batch_seconds"] for r in b1["rows"].values())
    identical = {k: all((work / k / c.name / "trajectory.txt").read_bytes()
                        == (work / "seq" / c.name / "trajectory.txt").read_bytes() for c in named) for k in ("b1", "b2")}

    fault_caps = named[:4]
    fault = fault_run(fault_caps, work / "fault", config)
    fault["identical_to_clean_runs"] = all((work / "fault" / c.name / "trajectory.txt").read_bytes()
                                           == (work / "seq" / c.name / "trajectory.txt").read_bytes() for c in fault_caps)

    per_run = statistics.mean(seq_walls)
    process_start = statistics.median(starts)
    dispatch = max(0.0, (b1_wall - cluster_start - cluster_close - task_total) / n)
    result = dict(
        machine=machine(), date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), captures=n, frames=args.frames,
        note="shared machine (other jobs running): compare figures within this invocation only",
        load_average=os.getloadavg(),
        process_start_s=round(process_start, 2), process_start_cpu_s=round(statistics.median(start_cpu), 2), cluster_start_s=round(cluster_start, 2),
        cluster_close_s=round(cluster_close, 2),
        sequential=dict(total_s=round(seq_total, 1), before_s=round(seq_total_a, 1), after_s=round(seq_total_b, 1),
                        per_capture_s=round(per_run, 2), cpu_s=round((CPU["seq"] + CPU["seq_again"]) / 2, 1),
                        slam_seconds_per_capture=round(statistics.mean(seq_runs), 2)),
        batch_1_worker=dict(total_s=round(b1_wall, 1), ratio_to_sequential=round(b1_wall / seq_total, 3),
                            cpu_s=round(b1["cpu_s"], 1),
                            cpu_ratio_to_sequential=round(2 * b1["cpu_s"] / (CPU["seq"] + CPU["seq_again"]), 3),
                            exit_code=b1["exit_code"], task_seconds_per_capture=round(task_total / n, 2),
                            scheduler_seconds_per_capture=round(dispatch, 3),
                            overhead_per_capture_s=round((b1_wall - seq_total) / n, 2),
                            trajectories_identical_to_sequential=identical["b1"]),
        batch_2_workers=dict(total_s=round(b2_wall, 1), speedup_vs_1_worker=round(b1_wall / b2_wall, 3),
                             cpu_s=round(b2["cpu_s"], 1),
                             exit_code=b2["exit_code"], trajectories_identical_to_sequential=identical["b2"]),
        fault=fault,
        scaling=dict(model="T(C captures, N machines, W runs each) ~= cluster_start + ceil(C / (N*W)) * "
                     "(run + process_start + scheduler) + cluster_close",
                     run_s=round(per_run - process_start, 2), fixed_s=round(cluster_start + cluster_close, 2),
                     per_capture_extra_s=round(process_start + dispatch, 2)),
    )
    print(json.dumps(result, indent=1))
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
