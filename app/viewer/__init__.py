"""The web viewer (viser): scene layers, panels and tools built from MapSnapshots; no SLAM logic.

    app.py          ViewerApp: wiring and the update loop; build_viewer(server, source)
    feed.py         SnapshotFeed: the source's snapshots merged with a refined map (the viewer's one source)
    scene.py        the map's splat chunks per keyframe
    cameras.py      keyframe frustums (the newest with images), trajectories, the current camera
    framing.py      the default view: frames the map on every page until its visitor moves the camera
    scrub.py        keyframe scrubbing, per page (its own Keyframes panel and view of the map)
    panels.py       status, plots and the live images panel; the shared run controls
    control_gui.py  GUI built only on the pages of visitors who may control the run
    access.py       access tokens, view-only pages, a websocket reader that drops malformed messages
    page_shim.py    a script served with viser 1.1.1's page: splat geometry bounds (no NaN console errors)
    novel_view.py   renders the map from the browser's camera (one render thread)
    export_panel.py, video_panel.py, refine_panel.py, measure.py: the tools
"""

from .app import StaticSource, ViewerApp, build_viewer

__all__ = ["StaticSource", "ViewerApp", "build_viewer"]
