"""The viewer's one export path: the current map (live or browsed) in any `splatam export` format,
or the estimated trajectory (TUM), offered for download and written into the export folder.

The map comes from the latest MapSnapshot (immutable numpy copies), never from the live
optimiser's tensors, and the export runs on its own thread, so SLAM goes on beside it. Files go
to EXPORT_DIR/exports/map.<suffix> (a subfolder, so a browsed run's own map.ply is never
replaced), or to a temporary folder when the viewer has no export folder. The panel is built on
the pages of visitors who may control the run (`gui`: a ControlGui), not on view-only pages; the
format is each page's own choice, the button exports what the page that pressed it chose.
"""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path

import viser

from splat_core.errors import InputError

from .download import produce_and_send
from ..exports import EXPORT_SUFFIXES, FORMATS, export_map


LABELS = {"ply": "3DGS .ply", "splat": ".splat (antimatter15)", "spz": ".spz (Niantic)",
          "compressed-ply": ".compressed.ply (SuperSplat)", "html": "standalone .html page",
          "trajectory": "trajectory.txt (TUM, camera-to-world)", "mesh": "mesh .ply (TSDF of a finished run)"}

STATE_NOTES = {"running": "Exports the map as it is now; SLAM keeps running.",
               "starting": "Exports the map as it is now; SLAM keeps running.",
               "paused": "Exports the map as it is now (SLAM is paused).",
               "finished": "Exports the finished run's map.",
               "stopped": "Exports the map of the stopped run.",
               "error": "Exports the map as SLAM left it.",
               "browse": "Exports the map being browsed."}


class ExportPanel:
    def __init__(self, server: viser.ViserServer, source, *, gui, export_dir: Path | None = None,
                 order: float = 4, mesh=None):
        """`gui`: a ControlGui (control_gui.py), which gives each page its own format choice."""
        self.source = source                # latest() -> MapSnapshot | None
        self.mesh = mesh                    # a MeshLayer: offers the "mesh" entry
        self.export_dir = Path(export_dir) / "exports" if export_dir else None
        self._busy = threading.Lock()
        self.exports = 0
        where = f"into `{self.export_dir}`" if self.export_dir else "into a temporary folder"
        with gui.add_folder("Export", order=order):
            self.format = gui.add_dropdown("Format", tuple(LABELS[f] for f in self.formats),
                                           initial_value=LABELS[FORMATS[0]], per_page=True,
                                           hint=format_hint(self.formats) + " (this page only)")
            self.button = gui.add_button("Export and download", icon=viser.Icon.DOWNLOAD,
                                         hint=f"Downloads the file and writes it {where}")
            self.note = gui.add_markdown(STATE_NOTES["running"])
            self.info = gui.add_markdown(f"Files are also written {where}.")
        self.button.on_click(self._on_click)

    @property
    def formats(self) -> tuple:
        return FORMATS + ("trajectory",) + (("mesh",) if self.mesh is not None else ())

    def selected_format(self, client_id: int | None = None) -> str:
        """The format chosen on that page (each page has its own choice)."""
        return next(f for f in self.formats if LABELS[f] == self.format.value_for(client_id))

    def follow(self, snap) -> None:
        """The note follows the run's state (running, paused, finished, browsing)."""
        note = STATE_NOTES.get(snap.state, STATE_NOTES["running"])
        if self.note.content != note:
            self.note.content = note

    def _on_click(self, event) -> None:
        fmt = self.selected_format(event.client_id)      # the choice of the page that pressed the button
        threading.Thread(target=self._export_and_send, args=(event.client, fmt), name="viewer-export",
                         daemon=True).start()

    def _export_and_send(self, client, fmt: str) -> None:
        produce_and_send(client, self.info, lambda: self.export(fmt), "export",
                         lambda path: (f"Exported {path.name}", f"written to {path}"))

    def export(self, fmt: str) -> Path | None:
        """Export the latest snapshot's map as `fmt`; the path written, or None while another
        export is running."""
        snap = self.source.latest()
        if snap is None or (fmt not in ("trajectory", "mesh") and snap.num_gaussians == 0):
            raise InputError("there is no map to export yet")
        if fmt == "trajectory" and len(snap.estimated_c2w) == 0:
            raise InputError("there is no trajectory to export yet")
        if not self._busy.acquire(blocking=False):
            return None
        try:
            self.button.disabled = True
            folder = self.export_dir or Path(tempfile.mkdtemp(prefix="splatam-export-"))
            if fmt == "mesh":
                self.info.content = "Building the mesh…"
                path = self.mesh.export(folder)
                self.exports += 1
                self.info.content = f"{path.name}: {path.stat().st_size:,} bytes, written to `{path}`"
                return path
            if fmt == "trajectory":
                from splat_core.io.atomic import write_bytes_atomic
                path = write_bytes_atomic(folder / "trajectory.txt", trajectory_bytes(snap))
                what = f"{len(snap.estimated_c2w)} poses"
            else:
                self.info.content = f"Exporting {snap.num_gaussians:,} Gaussians as {LABELS[fmt]}…"
                path = export_map(dict(snap.gaussians), fmt, folder / f"map{EXPORT_SUFFIXES[fmt]}")
                what = f"{snap.num_gaussians:,} Gaussians"
            self.exports += 1
            self.info.content = f"{path.name}: {what}, {path.stat().st_size:,} bytes, written to `{path}`"
            return path
        finally:
            self.button.disabled = False
            self._busy.release()


def format_hint(formats) -> str:
    """The Format dropdown's hint, naming every kind of file it offers."""
    kinds = ["The map (a splat file or a standalone .html page)"]
    if "trajectory" in formats:
        kinds.append("the estimated trajectory (TUM)")
    if "mesh" in formats:
        kinds.append("a mesh of a finished run (TSDF of its keyframes)")
    return kinds[0] if len(kinds) == 1 else ", ".join(kinds[:-1]) + " or " + kinds[-1]


def trajectory_bytes(snap) -> bytes:
    """The estimated trajectory as TUM text (c2w, the input's timestamps)."""
    from splat_core.io.trajectory import write_tum_trajectory

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trajectory.txt"
        write_tum_trajectory(path, snap.timestamps[: len(snap.estimated_c2w)], snap.estimated_c2w)
        return path.read_bytes()
