"""Small scripts served with viser 1.1.1's page: a bounding sphere for its Gaussian-splat geometry,
and fewer redraws where the browser draws WebGL in software.

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

Fewer redraws with software WebGL (issue 42: SLAM's rate with a browser on the same machine).
viser's page draws on demand, but also once a second (a heartbeat) and for 250 ms after every
scene message. Where WebGL is drawn by the CPU (SwiftShader, llvmpipe: no GPU, as on our 2-core
test machine), one draw of a 100k-splat map takes about 0.3 s of a core, so a page that merely
shows the map took half a core from SLAM (benchmarks/viewer.py). On such a page the second
script lets the view draw at most one animation frame every REDRAW_GAP_MS, except while the
person is using the page (pointer pressed or dragged, wheel, keys, touch: every frame then).
A frame asked for within the gap is not drawn (the canvas keeps the last one); viser's own
heartbeat asks for a frame every second, so the newest scene is drawn at most a second after the
gap ends. The gap was 2.5 s until 2026-12-07; on the Intel 2-core machine a draw of a 100k-splat map
cost Chromium about 2 core-seconds, and 5 s halved the draws during a SLAM run and the browser's
CPU (0.44-0.47 -> 0.26-0.27 cores; SLAM in the viewer 0.75x -> 0.79x of headless, pooled over
nine runs each: less than the runs' spread; docs/benchmarks.md, Viewer).
How: the same devtools hook tells about every WebGLRenderer, whose `render` is wrapped;
the first draw call of an animation frame decides for all its calls, and only draws to the
canvas are held: a draw with a camera never used before (viser's get_render capture makes a new
one each time) or to an off-screen target (environment maps) is never held. `?redraw=full` in the page's URL turns it off,
`?redraw=slow` on (with a GPU too); `window.__splatamRedraw` says which and counts draws.

Such a page also says so to the server: the script adds `splatam_webgl=software` to the URL of
the websocket viser's page opens (viser 1.1.1 opens it in a web worker, to which the page posts
the URL in a `set_server` message: the script wraps Worker.postMessage for that one message), and
the server counts those websockets while they are open (`software_pages(server)`). With
`--draw-while-running auto` (the default) the map is drawn as points while SLAM runs whenever
such a page is connected (app/viewer/scene.py): a point costs SwiftShader a tenth of a splat
(docs/benchmarks.md, Viewer).

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
import weakref
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger(__name__)

SHIM_VISER_VERSIONS = ("1.1.1",)
MARKER = "splatam-viewer: splat bounds"
REDRAW_GAP_MS = 5000       # a software-WebGL page draws its view at most this often...
REDRAW_INPUT_MS = 1500     # ...unless the page had input this recently
SOFTWARE_PARAM = "splatam_webgl"   # in a software-WebGL page's websocket URL: =software

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

SOFTWARE_REDRAW_JS = """(function () {
  /* splatam-viewer: software redraws (app/viewer/page_shim.py): with WebGL drawn by the CPU, the
     view draws at most every %(gap)d ms unless the page is in use. */
  var mode = new URLSearchParams(window.location.search).get("redraw");
  function drawsInSoftware() {
    try {
      var gl = document.createElement("canvas").getContext("webgl");
      if (!gl) return false;
      var info = gl.getExtension("WEBGL_debug_renderer_info");
      var name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
      var lose = gl.getExtension("WEBGL_lose_context");
      if (lose) lose.loseContext();
      return /swiftshader|llvmpipe|softpipe|software/i.test(name);
    } catch (e) { return false; }
  }
  var software = drawsInSoftware();
  var state = window.__splatamRedraw = {slow: mode === "slow" || (mode !== "full" && software),
                                         software: software, drawn: 0, held: 0};
  if (software && window.Worker) {
    /* tell the server (its websocket's URL says so): it may draw the map as points while SLAM
       runs. viser 1.1.1 opens the websocket in a worker, sending it the URL as {type: "set_server"} */
    var post = window.Worker.prototype.postMessage;
    window.Worker.prototype.postMessage = function (data) {
      var args = Array.prototype.slice.call(arguments);
      if (data && data.type === "set_server" && typeof data.server === "string") {
        try {
          var u = new URL(data.server, window.location.href);
          u.searchParams.set("%(param)s", "software");
          args[0] = Object.assign({}, data, {server: u.toString()});
        } catch (e) { /* the URL as it was */ }
      }
      return post.apply(this, args);
    };
  }
  if (!state.slow) return;
  var input = -1e9;
  function used() { input = performance.now(); }
  ["pointerdown", "wheel", "keydown", "touchstart", "touchmove"].forEach(function (type) {
    window.addEventListener(type, used, {capture: true, passive: true});
  });
  window.addEventListener("pointermove", function (e) { if (e.buttons) used(); }, {capture: true, passive: true});
  var frame = 0, raf = window.requestAnimationFrame.bind(window);   /* which animation frame runs */
  window.requestAnimationFrame = function (cb) { return raf(function (t) { frame = t; cb(t); }); };
  var decided = null, hold = false, last = -1e9, seen = new WeakSet();
  var hook = window.__THREE_DEVTOOLS__ || (window.__THREE_DEVTOOLS__ = new EventTarget());
  hook.addEventListener("observe", function (event) {
    var r = event.detail;
    if (!r || r.isWebGLRenderer !== true || typeof r.render !== "function") return;
    var render = r.render;
    r.render = function (scene, camera) {
      if (decided !== frame) {           /* the frame's first draw call decides for the whole frame */
        decided = frame;
        var now = performance.now();
        hold = now - input >= %(input)d && now - last < %(gap)d;
        if (hold) { state.held++; } else { last = now; state.drawn++; }
      }
      /* held: draws to the canvas with a camera seen before; a new camera (viser's get_render
         capture makes one each time) and off-screen passes (environment maps) always draw */
      if (hold && camera && seen.has(camera) && r.getRenderTarget() === null) return;
      if (camera) seen.add(camera);
      return render.apply(r, arguments);
    };
  });
})();""" % {"gap": REDRAW_GAP_MS, "input": REDRAW_INPUT_MS, "param": SOFTWARE_PARAM}

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
        log.warning("viser's page has no <head>: served without the page scripts")
        return html
    at = head + len("<head>")
    return f"{html[:at]}<script>{SPLAT_BOUNDS_JS}\n{SOFTWARE_REDRAW_JS}</script>{html[at:]}"


class SoftwarePages:
    """The websockets of the pages that said they draw WebGL in software (their page script adds
    SOFTWARE_PARAM=software to the websocket's URL); `count()`: those still connected."""

    def __init__(self):
        self._connections = weakref.WeakSet()
        self._lock = threading.Lock()

    def add(self, connection) -> None:
        with self._lock:
            self._connections.add(connection)

    def count(self) -> int:
        from websockets.protocol import State

        live = (State.CONNECTING, State.OPEN)
        with self._lock:
            return sum(1 for c in self._connections if getattr(c, "state", State.CLOSED) in live)


_pages_of: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # server -> its SoftwarePages


def attach(server, pages: SoftwarePages) -> None:
    """Remember which SoftwarePages (from `serving()`) hear `server`'s handshakes."""
    _pages_of[server] = pages


def software_pages(server) -> int:
    """How many pages connected to `server` draw WebGL in software (0 for a server not made
    through `serving()` and `attach()`, or a viser version the shim does not know)."""
    pages = _pages_of.get(server)
    return pages.count() if pages is not None else 0


def _says_software(request) -> bool:
    if request.headers.get("Upgrade", "").lower() != "websocket":
        return False
    return parse_qs(urlsplit(request.path).query).get(SOFTWARE_PARAM) == ["software"]


def wrap(inner, pages: SoftwarePages | None = None):
    """viser's process_request, its page answered with `patch_page` applied (other files as they
    are); a websocket handshake from a page that draws in software is added to `pages`."""
    cache: dict[bytes, bytes] = {}       # viser's cached bodies (plain, gzip) -> patched

    def process_request(connection, request):
        response = inner(connection, request) if inner is not None else None
        if response is None and pages is not None and _says_software(request):
            pages.add(connection)
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
    applied outside this one, the first outermost. Yields the SoftwarePages its handshakes fill
    (`attach` it to the server made)."""
    import websockets.asyncio.server as ws_server

    pages = SoftwarePages()
    with _serve_lock:
        original = ws_server.serve

        def serve(*args, **kwargs):
            process_request = kwargs.get("process_request")
            if applies():
                process_request = wrap(process_request, pages)
            for outer_wrap in reversed(outer):
                process_request = outer_wrap(process_request)
            kwargs["process_request"] = process_request
            return original(*args, **kwargs)
        ws_server.serve = serve
        try:
            yield pages
        finally:
            ws_server.serve = original
