"""The web viewer (viser): scene layers, panels and tools built from MapSnapshots; no SLAM logic.

    app.py          ViewerApp: wiring and the update loop; build_viewer(server, source)
    scene.py        the 3D layers: map splats, cameras, trajectories, frustums
    panels.py       status, plots and the live images panel
    novel_view.py   renders the map from the browser's camera (one render thread)
    export_panel.py, video_panel.py, refine_panel.py, measure.py: the tools
"""

from .app import StaticSource, ViewerApp, build_viewer

__all__ = ["StaticSource", "ViewerApp", "build_viewer"]
