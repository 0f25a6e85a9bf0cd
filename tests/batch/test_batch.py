"""`splatam batch`: a local Dask cluster on 127.0.0.1 over tiny captures; a broken capture is
reported and the others finish; a rerun skips; --retry-failed reruns; a worker killed mid-run has
its capture resumed elsewhere with the same trajectory; Ctrl-C keeps finished runs. Plus the
parts that need no cluster: capture names, the plan, the summary, the report, the install hint."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from app.batch import state
from app.batch.captures import Capture, list_captures
from app.batch.report import trajectory_svg
from app.batch.summary import _loops, make_row, to_csv
from app.cli import splatam_main
from splat_core.errors import InputError
from helpers import captures as fixtures
from helpers.configs import TINY
from helpers.hold import Hold
from helpers.viewer import wait_until

ROOT = Path(__file__).resolve().parents[2]


def _broken(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / "rgb.txt").write_text("# a TUM capture whose depth.txt is missing\n")
    return path


def _batch_env():
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))


def _summary(out: Path) -> dict:
    return {r["name"]: r for r in json.loads((out / "summary.json").read_text())["captures"]}


@pytest.fixture()
def tiny(tmp_path):
    (tmp_path / "tiny.yaml").write_text(TINY)
    return tmp_path / "tiny.yaml"


# ----------------------------------------------------------------------------- without a cluster

def test_capture_names_list_file_and_missing_paths(tmp_path):
    for p in ("x/scene", "y/scene", "z/walk.zip"):
        (tmp_path / p).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / p).mkdir() if not p.endswith(".zip") else (tmp_path / p).write_bytes(b"")
    (tmp_path / "list.txt").write_text("# comment\n\nx/scene\n" + str(tmp_path / "z/walk.zip") + "\n")
    caps = list_captures([str(tmp_path / "y/scene")], tmp_path / "list.txt")
    assert [c.name for c in caps] == ["y_scene", "x_scene", "walk"]
    assert caps[1].path == str((tmp_path / "x/scene").resolve())
    with pytest.raises(InputError, match="nope: no such capture"):
        list_captures([str(tmp_path / "nope")])
    with pytest.raises(InputError, match="no captures"):
        list_captures([])


def test_plan_skips_finished_keeps_failed_and_resumes_killed(tmp_path):
    run = tmp_path / "r"
    run.mkdir()
    assert state.plan(run, 0, [], False) == "submit"                 # nothing yet
    (run / "checkpoint").mkdir()
    for f in ("state.npz", "meta.json"):
        (run / "checkpoint" / f).write_text("x")
    assert state.has_checkpoint(run) and state.plan(run, 0, [], False) == "submit"   # killed: resumed by the task
    (run / "metrics.json").write_text("{}")
    assert state.plan(run, 0, [], False) == "skip"
    assert state.plan(run, 0, ["spz"], False) == "submit"            # an export not made yet
    state.write_status(run, {"status": "done", "exports": {"spz": "export/map.spz"}})
    (run / "export").mkdir()
    (run / "export/map.spz").write_bytes(b"x")
    assert state.plan(run, 0, ["spz"], False) == "skip"
    state.update_status(run, status="failed", error="boom")
    assert state.plan(run, 0, [], False) == "failed" and state.plan(run, 0, [], True) == "submit"
    assert state.export_output("colmap") == "export/colmap" and state.export_output("ply") == "export/map.ply"


def test_summary_row_and_report_plot(tmp_path):
    run = tmp_path / "a"
    run.mkdir()
    metrics = dict(frames=3, wall_seconds_per_frame=0.5, ate_rmse_cm=1.25, psnr=30.0, depth_l1_cm=2.0, num_gaussians=10,
                   frames_lost=1, frames_skipped=0, per_frame=[{"wall_seconds": 0.5}] * 3, loop_closures=[{}, {}])
    (run / "metrics.json").write_text(json.dumps(metrics))
    row = make_row(Capture("a", "/cap/a"), dict(status="done", seconds=2.0, attempts=1), tmp_path)
    assert (row["frames"], row["seconds"], row["ate_rmse_cm"], row["loops"], row["batch_seconds"]) == (3, 1.5, 1.25, 2, 2.0)
    assert _loops({"loops": {"count": 4}}) == 4 and _loops({}) is None
    csv = to_csv([row]).splitlines()
    assert len(csv) == 2 and csv[1].startswith("a,done,3,1.5,0.5,1.25")
    import numpy as np
    svg = trajectory_svg(np.array([[0.0, 0.0], [0.1, 0.2]]), np.array([[0.0, 0.0], [0.1, 0.25]]))
    assert svg.count("<polyline") == 2 and 'class="estimate"' in svg and 'class="reference"' in svg
    assert "no trajectory" in trajectory_svg(None, None)


def test_without_dask_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)      # import distributed -> ImportError
    code = splatam_main(["batch", str(tmp_path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    from app.console_commands import pip_install
    assert code == 2 and err == [f"error: splatam batch needs Dask: {pip_install('splatam-viewer[batch]')}"]


def test_bad_options_exit_2(tmp_path, capsys):
    pytest.importorskip("distributed")
    (tmp_path / "cap").mkdir()
    assert splatam_main(["batch", str(tmp_path / "cap"), "--out", str(tmp_path / "o"), "--export", "gif"]) == 2
    assert "--export gif: unknown format" in capsys.readouterr().err
    assert splatam_main(["batch", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2


def test_layout_gpu_slots_cpu_cores_and_a_remote_cluster_without_the_resource(monkeypatch):
    from app.batch import cluster
    monkeypatch.setattr(cluster, "local_gpus", lambda: ["0", "1", "2", "3"])
    monkeypatch.setattr(cluster, "machine_cores", lambda: 16)
    gpu = cluster.local_layout("auto", None, None, 2)
    assert (gpu.workers, gpu.task_resources, gpu.gpu_slots, gpu.cores_per_run) == (2, {"GPU": 2}, {0: "0,1", 1: "2,3"}, 8)
    cpu = cluster.local_layout("cpu", None, None, None)                # GPUs ignored; 4 cores a run by default
    assert cpu.task_resources == {"CPU": 4} and cpu.gpu_slots == {} and 1 <= cpu.workers <= 4
    assert cluster.local_layout("cpu", 2, None, None).task_resources == {"CPU": 8}
    monkeypatch.setattr(cluster, "local_gpus", lambda: [])
    with pytest.raises(InputError, match="no NVIDIA GPU"):
        cluster.local_layout("cuda", None, None, None)

    class FakeClient:          # a running cluster whose one worker offers no GPU
        scheduler = type("S", (), {"address": "tcp://10.0.0.1:8786"})()

        def scheduler_info(self):
            return {"workers": {"w": {"resources": {"CPU": 16}}}}
    assert cluster.remote_layout(FakeClient(), "auto", None, None).task_resources == {"CPU": 16}
    with pytest.raises(InputError, match="no worker offers the resource GPU=1.*--resources GPU=N"):
        cluster.remote_layout(FakeClient(), "auto", None, 1)


# ----------------------------------------------------------------------------- on a local cluster

@pytest.mark.slow
def test_batch_reports_a_broken_capture_skips_on_rerun_and_retries_failed(tmp_path, tiny, capsys):
    pytest.importorskip("distributed")
    caps = tmp_path / "caps"
    for name in ("a", "b", "c"):
        fixtures.write_tum(caps / name, n=4)
    _broken(caps / "broken")
    out = tmp_path / "out"
    args = ["batch", *(str(caps / n) for n in ("a", "b", "broken", "c")), "--out", str(out), "--config", str(tiny),
            "--workers", "2", "--export", "spz"]
    assert splatam_main(args) == 1                                   # one failed
    err = capsys.readouterr().err
    assert "cluster: local on tcp://127.0.0.1:" in err and "2 worker(s)" in err
    rows = _summary(out)
    assert {n: r["status"] for n, r in rows.items()} == {"a": "done", "b": "done", "broken": "failed", "c": "done"}
    assert "depth.txt is missing" in rows["broken"]["error"] and "\n" not in rows["broken"]["error"]
    for n in "abc":
        assert rows[n]["frames"] == 4 and rows[n]["ate_rmse_cm"] is not None and rows[n]["gaussians"] > 0
        assert (out / n / "export/map.spz").stat().st_size > 0 and (out / n / "trajectory.txt").is_file()
    page = (out / "index.html").read_text()
    assert page.count('class="estimate"') == 3 and page.count('class="reference"') == 3
    assert 'href="a/export/map.spz"' in page and "depth.txt is missing" in page
    assert len((out / "summary.csv").read_text().splitlines()) == 5 and "| broken | failed |" in (out / "summary.md").read_text()

    stamp = (out / "a" / "metrics.json").stat().st_mtime_ns
    assert splatam_main(args) == 1                                   # rerun: nothing runs, no cluster
    err = capsys.readouterr().err
    assert "cluster:" not in err and "--retry-failed reruns" in err
    assert {n: r["status"] for n, r in _summary(out).items()} == {"a": "skipped", "b": "skipped", "broken": "failed",
                                                                 "c": "skipped"}
    assert (out / "a" / "metrics.json").stat().st_mtime_ns == stamp

    (out / "broken" / "batch.log").unlink()
    assert splatam_main(args + ["--workers", "1", "--retry-failed"]) == 1   # reruns the failed one only
    rows = _summary(out)
    assert rows["broken"]["status"] == "failed" and rows["broken"]["attempts"] == 2
    assert "depth.txt is missing" in (out / "broken" / "batch.log").read_text()
    assert rows["a"]["status"] == "skipped" and (out / "a" / "metrics.json").stat().st_mtime_ns == stamp


def _wait_gone(pids, psutil, timeout=5.0):
    """The processes among `pids` still running after `timeout` s (a zombie counts as gone)."""
    def running(p):
        try:
            return psutil.Process(p).status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False
    deadline = time.time() + timeout
    while (alive := [p for p in pids if running(p)]) and time.time() < deadline:
        time.sleep(0.05)
    return alive


@pytest.mark.slow
def test_a_worker_killed_mid_run_is_retried_and_resumes_to_the_same_trajectory(tmp_path, tiny):
    pytest.importorskip("distributed")
    import psutil   # a dependency of distributed
    caps = tmp_path / "caps"
    fixtures.write_tum(caps / "a", n=9)
    import shutil
    shutil.copytree(caps / "a", caps / "b")                          # the same capture twice
    out = tmp_path / "out"
    # a's run is held after its first checkpoint (frame 3 of 9): its worker is killed while the run
    # has started and cannot have finished, whatever the load; the retry finds the hold done and goes on.
    hold = Hold(tmp_path / "hold", ["a"])
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "batch", *(str(caps / n) for n in "ab"), "--out",
                             str(out), "--config", str(tiny), "--workers", "2", "--quiet"], env=hold.env(_batch_env()),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: proc.poll() is not None or hold.held("a"), timeout=300, interval=0.05,
                   what="a's run to reach its first checkpoint")
        assert proc.poll() is None, proc.communicate()[0].decode()
        pid = state.read_status(out / "a")["pid"]                     # the Dask worker running a's task
        child = [c.pid for c in psutil.Process(pid).children()]       # its `splatam run`, held
        os.kill(pid, signal.SIGKILL)
        alive = _wait_gone(child, psutil, timeout=60)
        output = proc.communicate(timeout=300)[0].decode()
    finally:
        proc.kill()
    assert proc.returncode == 0, output
    rows = _summary(out)
    assert rows["a"]["status"] == "resumed" and rows["a"]["attempts"] == 2
    assert rows["b"]["status"] == "done"
    trajectories = {(out / n / "trajectory.txt").read_bytes() for n in "ab"}
    assert len(trajectories) == 1                                    # sequential engine: identical
    assert len(state.read_metrics(out / "a")["per_frame"]) == 9
    assert child and not alive                                       # the killed worker's run died with it


@pytest.mark.slow
def test_ctrl_c_keeps_finished_runs_writes_the_summary_and_the_rerun_resumes(tmp_path, tiny):
    pytest.importorskip("distributed")
    caps = tmp_path / "caps"
    fixtures.write_tum(caps / "a", n=3)
    fixtures.write_tum(caps / "b", n=6)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "app.cli", "batch", str(caps / "a"), str(caps / "b"), "--out", str(out),
           "--config", str(tiny), "--workers", "2", "--quiet"]
    # b's run is held after its first checkpoint (frame 3 of 6) until Ctrl-C ends it: Ctrl-C comes once a
    # is done and b has started, and b cannot have finished by then, whatever the load. (Waiting for
    # "a done and b checkpointed" alone let b finish first on a loaded machine.)
    hold = Hold(tmp_path / "hold", ["b"])
    proc = subprocess.Popen(cmd, env=hold.env(_batch_env()), start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: proc.poll() is not None or (state.read_status(out / "a").get("status") == "done"
                                                       and hold.held("b")),
                   timeout=300, interval=0.05, what="a done and b held after its first checkpoint")
        assert proc.poll() is None, proc.communicate()[0].decode()
        os.killpg(proc.pid, signal.SIGINT)                           # Ctrl-C in a terminal: the whole group
        output = proc.communicate(timeout=120)[0].decode()
    finally:
        proc.kill()
    assert proc.returncode == 130, output
    rows = _summary(out)
    assert rows["a"]["status"] == "done" and rows["b"]["status"] == "interrupted"
    assert not (out / "b/metrics.json").exists() and (out / "index.html").is_file()
    assert subprocess.run(cmd, env=_batch_env()).returncode == 0     # no hold now
    rows = _summary(out)
    assert rows["a"]["status"] == "skipped" and rows["b"]["status"] == "resumed" and rows["b"]["frames"] == 6
