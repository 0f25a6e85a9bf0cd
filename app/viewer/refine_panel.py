"""The viewer's Refine panel: refine a finished run's map in a background thread, then show it.

    panel = RefinePanel(server, feed, gui=controls)   # in ViewerApp; feed: the viewer's SnapshotFeed
    panel.sync(snap)                                   # every applied snapshot: enables the button
    panel.start()                                      # what the "Refine" button does

The button is enabled once SLAM has finished into a run folder (`--out`) or when browsing a run
folder. The job (splat_core.refine.RefineJob: the same as `splatam refine`, so it resumes from and
leaves the same files) runs in its own thread; the panel shows its progress and publishes the map being refined into
the viewer's snapshot feed (feed.py): a copy every `publish_seconds` while it runs (so the
browser shows the map sharpening), the refined map once it has finished. The feed, not this
panel, owns the viewer's data source. The panel is built on the pages of visitors who may
control the run (`gui`: a ControlGui).
Closing the viewer mid-refine stops the job at the next iteration and checkpoints it.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import viser

from splat_core.errors import InputError

from ..snapshot import MapSnapshot, VersionArrays
from .feed import READY_STATES

log = logging.getLogger(__name__)


class RefinePanel:
    def __init__(self, server: viser.ViserServer, feed, *, gui=None, iterations: int = 1000,
                 order: int = 6, update_seconds: float = 0.5, publish_seconds: float = 15.0):
        self.feed = feed
        self._update_seconds, self._publish_seconds = update_seconds, publish_seconds
        gui = gui if gui is not None else server.gui
        with gui.add_folder("Refine", order=order, expand_by_default=False):
            self.iterations = gui.add_number("Iterations", initial_value=iterations, min=1, step=100)
            self.resolution = gui.add_dropdown("Resolution", ("capture", "working"), initial_value="capture")
            self.button = gui.add_button("Refine", icon=viser.Icon.SPARKLES, disabled=True,
                                         hint="Optimise the finished map over all keyframes (as splatam refine); "
                                              "the page shows it sharpening")
            self.progress = gui.add_progress_bar(0.0, animated=False, visible=False)
            self.info = gui.add_markdown(idle_note("starting", None))
        self.button.on_click(lambda _: self.start())
        self._run_dir: Path | None = None
        self._stop = threading.Event()
        self._note_lock = threading.Lock()  # the idle note is never written over a started job's words
        self.thread: threading.Thread | None = None
        self.result: dict | None = None      # the metrics.json refine section once done
        self.error: str | None = None

    # ------------------------------------------------------------------ state
    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    @property
    def published(self) -> int:
        """Maps handed to the viewer so far (during and after refine jobs)."""
        return self.feed.refined()[1]

    def sync(self, snap: MapSnapshot) -> None:
        """Enable the button when `snap` is a finished run with a folder (called on every viewer pull)."""
        run_dir = Path(snap.out_dir) if snap.state in READY_STATES and snap.out_dir else None
        self._run_dir = run_dir
        disabled = run_dir is None or self.running
        if self.button.disabled != disabled:
            self.button.disabled = disabled
        with self._note_lock:
            if self.thread is None:          # before any job: the note says what Refine will do, or when
                note = idle_note(snap.state, run_dir)
                if self.info.content != note:
                    self.info.content = note

    # ------------------------------------------------------------------ the job
    def start(self) -> bool:
        """Start refining the current run folder in the background; False when not possible now."""
        if self.running or self._run_dir is None:
            return False
        self.button.disabled = True
        self.progress.value, self.progress.visible = 0.0, True
        self.result = self.error = None
        self._stop.clear()
        with self._note_lock:
            self.thread = threading.Thread(target=self._run, name="refine", daemon=True,
                                           args=(self._run_dir, int(self.iterations.value), self.resolution.value))
        self.thread.start()
        return True

    def _run(self, run_dir: Path, iterations: int, resolution: str) -> None:
        from splat_core.refine import RefineJob, RefineSettings

        job = None
        try:
            self.info.content = "Loading the keyframes and the SLAM map's held-out metrics…"
            job = RefineJob(run_dir, RefineSettings(iterations=iterations), resolution=resolution)
            shown = published = time.monotonic()
            while not job.done:
                if self._stop.is_set():
                    job.save_checkpoint()
                    self.info.content = f"Stopped at iteration {job.iteration}; Refine again resumes."
                    return
                loss = job.step()
                if time.monotonic() - shown > self._update_seconds or job.done:
                    shown = time.monotonic()
                    self.progress.value = 100.0 * job.iteration / job.total
                    self.info.content = (f"Iteration {job.iteration} / {job.total}: loss {loss:.4f}, "
                                         f"{len(job.refiner.map):,} Gaussians, "
                                         f"{job.seconds / job.iteration:.2f} s/it")
                if time.monotonic() - published >= self._publish_seconds and not job.done:
                    published = time.monotonic()
                    self._publish(job)
            self.info.content = "Evaluating the refined map on the held-out frames…"
            self.result = job.finish()
            self._publish(job)
            self.info.content = summary_markdown(self.result)
        except InputError as e:
            self.error = str(e)
            self.info.content = f"**Refine failed:** {e}"
        except Exception as e:   # shown, never raised into the viewer
            log.exception("refine failed")
            self.error = f"{type(e).__name__}: {e}"
            self.info.content = f"**Refine failed:** {self.error}"
        finally:
            self.progress.visible = False
            self.button.disabled = self._run_dir is None

    def _publish(self, job) -> None:
        """Show the job's map as it stands (a published copy: the job goes on stepping its tensors)."""
        self.feed.publish_refined(VersionArrays(job.refiner.publish()))

    def close(self, timeout: float = 30.0) -> None:
        self._stop.set()
        if self.thread is not None:
            self.thread.join(timeout)


def idle_note(state: str, run_dir: Path | None) -> str:
    """The panel's note before a job: what Refine writes, or why it is not offered yet."""
    from splat_core.run.run_folder import REFINED_MAP

    if run_dir is not None:
        return f"Refine the finished map over all keyframes; writes `{run_dir / REFINED_MAP}`."
    if state in ("starting", "running", "paused"):
        return "Refine the map over all keyframes once SLAM has finished writing the run folder."
    if state == "browse":
        return "Refining needs a run folder (its keyframes): open one with `splatam-viewer --open RUN_DIR`."
    return "Refine is offered for a run that has finished."


def summary_markdown(section: dict) -> str:
    before, after = section["before"], section["after"]
    lines = [f"Refined: **{section['iterations']}** iterations at {section['size'][0]}x{section['size'][1]}, "
             f"{section['seconds_per_iteration']:.2f} s/it, {section['num_gaussians_after']:,} Gaussians; "
             f"`{section['output']}` written."]
    if after["psnr"] is not None:
        lines.append(f"Held-out PSNR {before['psnr']:.2f} → **{after['psnr']:.2f} dB**, SSIM "
                     f"{before['ssim']:.3f} → {after['ssim']:.3f}, depth L1 {before['depth_l1_cm']:.2f} → "
                     f"{after['depth_l1_cm']:.2f} cm ({after['frames']} frames).")
    return "  \n".join(lines)
