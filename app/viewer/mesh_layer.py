"""The viewer's Mesh layer: a TSDF mesh of the finished run (`splatam export --format mesh`),
built on demand in a background thread, shown with viser's trimesh support, toggled against the
splats; and the mesh entry of the export panel.

    layer = MeshLayer(server, latest)   # in ViewerApp, before the map's first chunk is sent
    layer.sync(snapshot)                # each applied snapshot: enables "Build mesh" once ready
    layer.start()                       # what the button does: build in a thread, then show
    layer.export(folder)                # the export panel's "mesh" entry: the mesh as .ply

Ready when SLAM has finished into a run folder (`--out`) or a run folder is browsed (the mesh
fuses the run's frames as `splatam export` does: splat_core.export.build_mesh). The page gets a copy
of at most VIEWER_MAX_FACES faces (vertex clustering: splat_core.export.decimate); the export entry
writes the full mesh. The splat chunks hang under `/map`;
this layer owns that frame, so hiding it hides every chunk whatever the map layer sends later.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import viser

from splat_core.errors import InputError

log = logging.getLogger(__name__)

READY_STATES = ("finished", "browse")
MESH_NODE = "/mesh"
MAP_ROOT = "/map"
VIEWER_MAX_FACES = 200_000       # the synthetic 320x240 room's full mesh has 427k faces


class MeshLayer:
    def __init__(self, server: viser.ViserServer, latest, *, order: int = 7, gui=None):
        self.server, self.latest = server, latest
        self.map_root = server.scene.add_frame(MAP_ROOT, show_axes=False)
        self.mesh = None                 # trimesh.Trimesh once built
        self.handle = None
        self.run_dir: Path | None = None
        self._mesh_of: Path | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        gui = gui if gui is not None else server.gui   # the viewer's ControlGui: controlling pages only
        with gui.add_folder("Mesh", order=order, expand_by_default=False):
            self.button = gui.add_button("Build mesh", icon=viser.Icon.CUBE, disabled=True)
            self.show = gui.add_checkbox("Show mesh instead of splats", initial_value=True, disabled=True)
            self.info = gui.add_markdown("A mesh of the finished run (TSDF of its frames' depth).")
        self.button.on_click(lambda _event: self.start())
        self.show.on_update(lambda _event: self._apply_visibility())

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def sync(self, snap) -> None:
        ready = snap is not None and snap.state in READY_STATES and snap.out_dir is not None
        self.run_dir = Path(snap.out_dir) if ready else None
        self.button.disabled = not ready or self.busy

    def start(self) -> threading.Thread | None:
        """Build the mesh in a background thread (None when one is already running or not ready)."""
        with self._lock:
            if self.busy or self.run_dir is None:
                return None
            self.button.disabled = True
            self._thread = threading.Thread(target=self._build_and_show, args=(self.run_dir,),
                                            name="viewer-mesh", daemon=True)
            self._thread.start()
            return self._thread

    def _build_and_show(self, run_dir: Path) -> None:
        try:
            from splat_core.export.decimate import decimate

            mesh = self.build(run_dir)
            shown = decimate(mesh, VIEWER_MAX_FACES)
            self.handle = self.server.scene.add_mesh_trimesh(MESH_NODE, shown, visible=bool(self.show.value))
            self.show.disabled = False
            self._apply_visibility()
            sent = "" if shown is mesh else f" ({len(shown.faces):,} shown)"
            self.info.content = (f"{len(mesh.faces):,} faces{sent}, voxel {mesh.metadata['voxel'] * 100:.1f} cm, "
                                 f"{mesh.metadata['fused']} frames fused "
                                 f"(`splatam export {run_dir} --format mesh --out FILE` writes the same)")
        except InputError as e:
            self.info.content = f"⚠ {e}"
        except Exception as e:   # noqa: BLE001 - shown in the panel; the viewer keeps running
            log.exception("mesh failed")
            self.info.content = f"⚠ mesh failed: {e}"
        finally:
            self.button.disabled = self.run_dir is None

    def build(self, run_dir: Path):
        """The run's mesh (built once per run folder), with progress in the panel."""
        from splat_core.export.mesh import build_mesh
        from splat_core.refine.run_data import load_run_data

        if self.mesh is not None and self._mesh_of == run_dir:
            return self.mesh
        self.info.content = "Loading the run…"
        run = load_run_data(run_dir)
        self.mesh = build_mesh(run, progress=self._progress, warn=log.warning)
        self._mesh_of = run_dir
        return self.mesh

    def _progress(self, iterable, total=None, desc="", **_kw):
        for n, item in enumerate(iterable):
            if total and n % max(1, total // 20) == 0:
                self.info.content = f"{desc.capitalize()}: {n} of {total}…"
            yield item

    def _apply_visibility(self) -> None:
        showing = self.handle is not None and bool(self.show.value)
        if self.handle is not None:
            self.handle.visible = showing
        self.map_root.visible = not showing

    def export(self, folder: Path) -> Path:
        """The export panel's mesh entry: the mesh as folder/mesh.ply (built first if needed)."""
        from splat_core.export.mesh import write_mesh

        if self.run_dir is None:
            raise InputError("a mesh needs a finished run folder: run with --out, or browse a run folder")
        return write_mesh(self.build(self.run_dir), Path(folder) / "mesh.ply")
