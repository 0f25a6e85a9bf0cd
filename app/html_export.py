"""A Gaussian map as one standalone HTML page: viser's embed page (`server.scene.as_html()`,
viser 1.1.1).

A throwaway viser server, bound to 127.0.0.1 on port 0, gets the map as one splat node (in
WORLD_SCALE units with `scale=1/WORLD_SCALE`, as the live viewer uploads it), the scene's up
direction (-y: OpenCV world axes) and an initial camera behind the world origin looking at the
middle of the map; `as_html()` serialises that scene into viser's client page and the server is
stopped. The page inlines the client (0.82 MB) and the scene (32 B per Gaussian, zstd,
base64), and opens from file:// without any network. It carries viewer.page_shim's script, as the
live viewer's page does.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from splat_core.io.atomic import write_text_atomic

from .viewer.page_shim import patch_page
from .viewer.scene import WORLD_SCALE, splat_payload


def html_page(arrays: dict) -> str:
    """The standalone HTML page (a str) showing the Gaussian `arrays` (GaussianMap.to_numpy())."""
    import viser

    payload = splat_payload(arrays)
    means = np.asarray(arrays["means"], np.float64).reshape(-1, 3)
    centre = np.median(means, axis=0) if len(means) else np.array([0.0, 0.0, 1.0])
    dist = max(float(np.linalg.norm(centre)), 0.3)
    # viser prints a banner on start and a line on stop; an export command should not.
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        try:
            server.scene.set_up_direction("-y")
            server.initial_camera.up = (0.0, -1.0, 0.0)
            server.initial_camera.look_at = tuple(centre)
            server.initial_camera.position = tuple(np.array([0.0, -0.3, -0.8]) * dist)
            if len(means):
                server.scene.add_gaussian_splats("/map", *payload, scale=1.0 / WORLD_SCALE)
            return patch_page(server.scene.as_html())
        finally:
            server.stop()


def write_html(path, arrays: dict) -> Path:
    """Write `html_page(arrays)` atomically; returns the path."""
    return write_text_atomic(path, html_page(arrays))
