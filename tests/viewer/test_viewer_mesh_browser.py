"""The viewer's Mesh layer in a real browser (as test_viewer_tools_browser.py): a browsed run
folder, "Build mesh" clicked in the page builds it in a background thread, the mesh shows
instead of the splats and toggles back, and the export panel's mesh entry downloads it."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from splat_core.config import load_config
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource

from helpers.browser import connect, look, render
from helpers.viewer import wait_until

pytestmark = [pytest.mark.browser]

TINY = """base: cpu
resolution: [64, 48]
checkpoint_every: 0
keyframes: {every: 2}
tracking: {iterations: 4}
mapping: {iterations: 3, first_frame_iterations: 20, window_size: 4}
"""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer_mesh")
    (root / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(SyntheticSource(n_frames=6, width=64, height=48), load_config(str(root / "tiny.yaml")), root / "run")
    while pipe.step() is not None:
        pass
    pipe.finish()
    return root / "run"


@pytest.mark.slow
def test_mesh_layer_and_mesh_export_in_the_page(browser, server, run_dir, tmp_path):  # noqa: F811
    from app.browse import load_run
    from app.viewer import StaticSource, build_viewer
    from app.viewer.export_panel import LABELS

    app = build_viewer(server, StaticSource(load_run(run_dir)), export_dir=tmp_path, render_backend="cpu")
    try:
        page, client = connect(browser, server)
        layer = app.mesh_layer
        wait_until(lambda: not layer.button.disabled, 30, what="Build mesh enabled")
        look(client, (0.0, 0.0, -0.5), (0.0, 0.0, 2.0))
        wait_until(lambda: app.map_layer.node_names, 30, what="splats sent")
        splats = render(client)
        page.get_by_text("Mesh", exact=True).first.click()                 # open the folder
        page.get_by_role("button", name="Build mesh").click()
        # the build thread sends the mesh, then shows it and writes its summary: wait for all of it
        wait_until(lambda: layer.handle is not None and "faces" in layer.info.content, 120, interval=0.25,
                   what="mesh built and sent")
        assert server.scene.get_handle_by_name("/mesh") is layer.handle
        wait_until(lambda: layer.handle.visible and not layer.map_root.visible, 30,
                   what="the mesh shown instead of the splats")
        assert len(layer.mesh.faces) > 500
        shown = {}

        def drawn(reference):
            shown["img"] = render(client)
            return np.abs(shown["img"] - reference).mean() > 1.0
        wait_until(lambda: drawn(splats), 60, interval=0.5, what="the page draws the mesh")
        mesh_img = shown["img"]
        page.get_by_text("Show mesh instead of splats").first.click()        # back to the splats
        wait_until(lambda: not layer.show.value and not layer.handle.visible and layer.map_root.visible, 30,
                   what="the toggle applied: the splats instead of the mesh")
        wait_until(lambda: drawn(mesh_img), 60, interval=0.5, what="splats again")
        # the export panel's mesh entry: the same mesh as a .ply download
        app.export_panel.format.value = LABELS["mesh"]
        with page.expect_download(timeout=120_000) as download:
            page.get_by_role("button", name="Export and download").click()
        assert download.value.suggested_filename == "mesh.ply"
        download.value.save_as(tmp_path / "downloaded.ply")
        got = trimesh.load(tmp_path / "downloaded.ply", force="mesh")
        assert len(got.faces) == len(layer.mesh.faces)
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        app.close()


def test_mesh_layer_waits_for_a_finished_run(server):
    """While SLAM runs (or with no run folder) the button stays off and export says why."""
    from pathlib import Path

    from app.viewer.mesh_layer import MeshLayer
    from splat_core.errors import InputError

    layer = MeshLayer(server, lambda: None)
    assert layer.button.disabled and layer.start() is None
    layer.sync(None)
    assert layer.button.disabled
    with pytest.raises(InputError, match="finished run folder"):
        layer.export(Path("/tmp"))
