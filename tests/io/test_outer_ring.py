"""The outer ring imports (and works) without torch: the run folder, atomic writes, the input
contract (FrameSource, LiveSource) and `splatam batch`'s driver side, whose Dask workers and
summaries only read run folders and write small files (docs/design.md, Layout)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "numba", "cv2")
RING = ("splat_core.run.run_folder", "splat_core.io.atomic", "splat_core.io.checkpoint", "splat_core.io.source",
        "app.batch", "app.batch.captures", "app.batch.state", "app.batch.summary", "app.batch.report",
        "app.batch.task", "app.batch.child", "app.batch.cluster", "app.batch.driver")

# Run before anything else in a fresh interpreter: importing a heavy package fails at once.
BLOCKER = f"""
import sys
class Blocked:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {HEAVY!r}:
            raise ImportError("blocked in the outer-ring test: " + name)
sys.meta_path.insert(0, Blocked())
"""


def run_without_heavy(body: str, tmp_path: Path) -> subprocess.CompletedProcess:
    script = BLOCKER + textwrap.dedent(body) + f"\nassert not [m for m in {HEAVY!r} if m in sys.modules]\nprint('ok')\n"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)


def test_the_outer_ring_imports_without_torch(tmp_path):
    body = "import importlib\n" + "".join(f"importlib.import_module({m!r})\n" for m in RING) + textwrap.dedent("""
        from splat_core.io.source import FrameSource, LiveSource
        assert issubclass(LiveSource, FrameSource) and LiveSource.live
    """)
    proc = run_without_heavy(body, tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-3000:]


def test_a_batch_reads_run_folders_and_writes_its_summary_without_torch(tmp_path):
    """Plan, summary row, report and export step of a finished run folder (trajectory, metrics,
    checkpoint meta with references), all in an interpreter where torch cannot be imported."""
    body = f"""
        import json
        from pathlib import Path
        import numpy as np
        from splat_core.run.run_folder import RunFolder
        from splat_core.io import checkpoint
        from app.batch import state
        from app.batch.captures import Capture
        from app.batch.report import write_report
        from app.batch.summary import make_row, write_summary
        from app.batch.task import export_command

        out = Path({str(tmp_path)!r}) / "batch"
        folder = RunFolder(out / "cap")
        folder.path.mkdir(parents=True)
        folder.trajectory.write_text("0 0 0 0 0 0 0 1\\n1 0.1 0 0.2 0 0 0 1\\n")
        refs = [np.eye(4).tolist(), np.eye(4).tolist()]
        checkpoint.save(folder.checkpoint_dir, dict(w2cs=np.zeros((2, 4, 4))), dict(frames_done=2, references=refs))
        folder.add_metrics_section("frames", 2)
        cap = Capture("cap", "/somewhere/cap")
        assert state.finished(folder.path) and state.has_checkpoint(folder.path)
        assert state.plan(folder.path, 0, [], False) == "skip"
        assert state.plan(folder.path, 5, [], False) == "submit"     # not refined yet
        state.write_status(folder.path, dict(status="done"))
        row = make_row(cap, dict(status="done"), out)
        assert row["frames"] == 2
        write_summary(out, [row], {{}})
        page = write_report(out, [cap], [row], {{}}).read_text()
        assert 'class="estimate"' in page and 'class="reference"' in page
        assert 'href="cap/map.ply"' not in page and 'href="cap/metrics.json"' in page
        assert export_command(folder.path, "ply", True)[1] == str(folder.refined_map)
        assert state.export_output("ply") == "export/map.ply"
    """
    proc = run_without_heavy(body, tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-3000:]


def test_the_nerfcapture_stream_is_a_live_source():
    from splat_core.io.nerfcapture_stream import NeRFCaptureStream
    from splat_core.io.source import LiveSource

    assert issubclass(NeRFCaptureStream, LiveSource)
