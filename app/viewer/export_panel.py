"""The viewer's export panel: the current map (live or browsed) in any `splatam export` format,
offered for download and written into the export folder.

The map comes from the latest MapSnapshot (immutable numpy copies), never from the live
optimiser's tensors, and the export runs on its own thread, so SLAM goes on beside it. Files go
to EXPORT_DIR/exports/map.<suffix> (a subfolder, so a browsed run's own map.ply is never
replaced), or to a temporary folder when the viewer has no export folder.
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
          "mesh": "mesh .ply (finished runs; mesh_layer.py)"}


class ExportPanel:
    def __init__(self, server: viser.ViserServer, source, *, export_dir: Path | None = None, folder=None,
                 mesh=None):
        self.source = source                # latest() -> MapSnapshot | None
        self.mesh = mesh                    # a MeshLayer: offers the "mesh" entry
        self.export_dir = Path(export_dir) / "exports" if export_dir else None
        self._busy = threading.Lock()
        self.exports = 0
        gui = server.gui
        with folder if folder is not None else gui.add_folder("Export"):   # the panel's Export folder
            self.format = gui.add_dropdown("Format", tuple(LABELS[f] for f in self.formats),
                                           initial_value=LABELS[FORMATS[0]])
            self.button = gui.add_button("Export and download", icon=viser.Icon.DOWNLOAD)
            self.info = gui.add_markdown("Exports the map as it is now; SLAM keeps running.")
        self.button.on_click(self._on_click)

    @property
    def formats(self) -> tuple:
        return FORMATS + (("mesh",) if self.mesh is not None else ())

    @property
    def selected_format(self) -> str:
        return next(f for f in self.formats if LABELS[f] == self.format.value)

    def _on_click(self, event) -> None:
        threading.Thread(target=self._export_and_send, args=(event.client, self.selected_format),
                         name="viewer-export", daemon=True).start()

    def _export_and_send(self, client, fmt: str) -> None:
        produce_and_send(client, self.info, lambda: self.export(fmt), "export",
                         lambda path: (f"Exported {path.name}", f"written to {path}"))

    def export(self, fmt: str) -> Path | None:
        """Export the latest snapshot's map as `fmt`; the path written, or None while another
        export is running."""
        snap = self.source.latest()
        if snap is None or snap.num_gaussians == 0:
            raise InputError("there is no map to export yet")
        if not self._busy.acquire(blocking=False):
            return None
        if fmt == "mesh":
            try:
                self.button.disabled = True
                self.info.content = "Building the mesh…"
                path = self.mesh.export(self.export_dir or Path(tempfile.mkdtemp(prefix="splatam-export-")))
                self.exports += 1
                self.info.content = f"{path.name}: {path.stat().st_size:,} bytes, written to `{path}`"
                return path
            finally:
                self.button.disabled = False
                self._busy.release()
        try:
            self.button.disabled = True
            self.info.content = f"Exporting {snap.num_gaussians:,} Gaussians as {LABELS[fmt]}…"
            folder = self.export_dir or Path(tempfile.mkdtemp(prefix="splatam-export-"))
            path = export_map(dict(snap.gaussians), fmt, folder / f"map{EXPORT_SUFFIXES[fmt]}")
            self.exports += 1
            self.info.content = (f"{path.name}: {snap.num_gaussians:,} Gaussians, "
                                 f"{path.stat().st_size:,} bytes, written to `{path}`")
            return path
        finally:
            self.button.disabled = False
            self._busy.release()
