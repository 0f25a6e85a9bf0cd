"""A small script served with viser 1.1.1's page: gives its Gaussian-splat geometry a bounding sphere.

Why (issue 32, defect 8): the browser console logged `THREE.BufferGeometry.computeBoundingSphere():
Computed radius is NaN` whenever a map update changed the number of splats or splat nodes
(every keyframe and most consolidations). viser 1.1.1 draws all splat nodes as one three.js
mesh (client/src/Splatting/GaussianSplats.tsx, `<mesh geometry={meshProps.geometry} ...>`)
whose InstancedBufferGeometry is rebuilt when that count changes
(GaussianSplatsHelpers.ts `createGaussianMeshProps`); its `position` attribute holds the 2-D
corners of the quad drawn per splat (itemSize 2: the splats themselves live in a texture). The
first render of each new geometry runs three.js's WebGLRenderer.projectObject, which calls
`geometry.computeBoundingSphere()` for frustum culling and again for depth-sorting transparent
objects; with no z component that sphere is NaN and three.js logs the error. Nothing in viser's
Python API reaches that mesh, so the count changes cannot be avoided without giving up the
per-keyframe chunks (scene.py).

What: the script registers as three.js's devtools hook (`window.__THREE_DEVTOOLS__`, an
EventTarget three.js tells about every Scene it creates) before viser's bundle runs, and wraps
each Scene's `onBeforeRender` (called before projectObject) so that a splat geometry without a
bounding sphere gets an unbounded one: centre 0, radius Infinity, what three.js itself assigns
when a position attribute cannot describe the bounds (GLBufferAttribute). three.js then computes
nothing. The mesh is drawn as before (a NaN sphere never culled it either); only the error goes.
A splat geometry is recognised by its shape (InstancedBufferGeometry, 2-component `position`,
a `sortedIndex` attribute); anything else is left alone.

How it is served: `serving()` wraps viser's `process_request` (as access.py does for tokens)
and inserts the script after `<head>` of the page; `patch_page()` does the same for a written
page (html_export.py). Only for the viser versions in SHIM_VISER_VERSIONS: another version
is served unchanged (check whether it still needs this before adding it there).
"""

from __future__ import annotations

import contextlib
import dataclasses
import gzip
import logging
import threading
from urllib.parse import urlsplit

log = logging.getLogger(__name__)

SHIM_VISER_VERSIONS = ("1.1.1",)
MARKER = "splatam-viewer: splat bounds"

SPLAT_BOUNDS_JS = """(function () {
  /* %s (app/viewer/page_shim.py): viser's splat quad geometry has a 2-D position attribute,
     so three.js would compute a NaN bounding sphere; give it an unbounded one first. */
  var hook = window.__THREE_DEVTOOLS__ || (window.__THREE_DEVTOOLS__ = new EventTarget());
  var Sphere = null;
  function bound(o) {
    var g = o.geometry, a = g && g.attributes;
    if (o.isMesh !== true || !a || g.boundingSphere !== null || g.isInstancedBufferGeometry !== true
        || !a.position || a.position.itemSize !== 2 || !a.sortedIndex) return;
    if (Sphere === null) {          /* three.js's Sphere class, from an empty geometry of the same kind */
      var probe = new g.constructor();
      probe.computeBoundingSphere();
      Sphere = probe.boundingSphere.constructor;
    }
    g.boundingSphere = new Sphere(undefined, Infinity);
  }
  hook.addEventListener("observe", function (event) {
    var scene = event.detail;
    if (!scene || scene.isScene !== true) return;
    var before = scene.onBeforeRender;
    scene.onBeforeRender = function () { scene.traverse(bound); return before.apply(this, arguments); };
  });
})();""" % MARKER

_serve_lock = threading.Lock()


def applies() -> bool:
    """Whether the installed viser is one this shim was written for."""
    import viser
    return getattr(viser, "__version__", None) in SHIM_VISER_VERSIONS


def patch_page(html: str) -> str:
    """The page with the script first in its <head> (unchanged if already there, if this viser is
    not one the shim knows, or if the page has no <head>)."""
    if MARKER in html or not applies():
        return html
    head = html.find("<head>")
    if head < 0:
        log.warning("viser's page has no <head>: served without the splat-bounds script")
        return html
    at = head + len("<head>")
    return f"{html[:at]}<script>{SPLAT_BOUNDS_JS}</script>{html[at:]}"


def wrap(inner):
    """viser's process_request, its page answered with `patch_page` applied (other files as they are)."""
    cache: dict[bytes, bytes] = {}       # viser's cached bodies (plain, gzip) -> patched

    def process_request(connection, request):
        response = inner(connection, request) if inner is not None else None
        if (response is None or response.status_code != 200
                or urlsplit(request.path).path not in ("/", "/index.html")
                or not response.headers.get("Content-Type", "").startswith("text/html")):
            return response
        body = response.body
        if body not in cache:
            gzipped = response.headers.get("Content-Encoding") == "gzip"
            html = (gzip.decompress(body) if gzipped else body).decode("utf-8")
            patched = patch_page(html).encode("utf-8")
            cache[body] = gzip.compress(patched, 6) if gzipped else patched
        headers = response.headers.copy()
        del headers["Content-Length"]
        headers["Content-Length"] = str(len(cache[body]))
        return dataclasses.replace(response, headers=headers, body=cache[body])
    return process_request


@contextlib.contextmanager
def serving(*outer):
    """Around `viser.ViserServer(...)`: its page is served with the script. viser 1.1.1 serves the
    page and its websocket from one `websockets.asyncio.server.serve(..., process_request=...)`
    call made while the constructor runs and exposes no hook, so `serve` is replaced for that
    time (under a lock). `outer`: further process_request wrappers (access.py's token check),
    applied outside this one, the first outermost."""
    import websockets.asyncio.server as ws_server

    with _serve_lock:
        original = ws_server.serve

        def serve(*args, **kwargs):
            process_request = wrap(kwargs.get("process_request")) if applies() else kwargs.get("process_request")
            for outer_wrap in reversed(outer):
                process_request = outer_wrap(process_request)
            kwargs["process_request"] = process_request
            return original(*args, **kwargs)
        ws_server.serve = serve
        try:
            yield
        finally:
            ws_server.serve = original
