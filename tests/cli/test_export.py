"""`splatam export` and `export_map`: every format read back against the map (count, positions
within 1 mm after undoing SPZ's axes, colours, opacities, scales, rotations), SPZ's RUB axes in
the file itself, one-line errors, atomic outputs, and the HTML page in headless Chromium."""

from __future__ import annotations

import io
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest

from app.cli import splatam_main
from app.exports import export_map
from splat_core.errors import InputError
from splat_core.io.compressed import CHUNK, is_compressed_ply, read_spz, spatial_order
from splat_core.io.map_files import read_map_file
from splat_core.io.ply import normalised_quaternions, sigmoid, write_ply

SPACING = 0.2   # grid spacing (m); jitter +-2 cm, so rounding to the grid identifies each Gaussian
SIDE = 16       # 16^3 = 4096 Gaussians (16 chunks) filling a 3 m cube


def grid_map(seed=0, isotropic=False):
    """Gaussians on a jittered 3 m grid, in random order, with random colours, opacities, scales
    and rotations. A 3 m cube needs the spatial order: in file order a compressed-PLY chunk
    would span the whole cube, and its 10-bit y would be 1.5 mm coarse."""
    rng = np.random.default_rng(seed)
    cells = np.stack(np.meshgrid(*[np.arange(SIDE)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = cells[rng.permutation(len(cells))]
    n = len(cells)
    return dict(
        means=(cells * SPACING + rng.uniform(-0.02, 0.02, (n, 3)) + [-1.5, -1.0, 0.5]).astype(np.float32),
        colors=rng.uniform(0, 1, (n, 3)).astype(np.float32),
        rotations=rng.normal(size=(n, 4)).astype(np.float32),
        logit_opacities=rng.normal(0, 2, n).astype(np.float32),
        log_scales=rng.uniform(-6, -2, (n, 1 if isotropic else 3)).astype(np.float32),
        birth_frame=np.zeros(n, np.int64),
    )


def cell_ids(means):
    cells = np.round((np.asarray(means, np.float64) - [-1.5, -1.0, 0.5]) / SPACING).astype(np.int64)
    return (cells[:, 0] * SIDE + cells[:, 1]) * SIDE + cells[:, 2]


# format -> tolerances: colour, opacity (after sigmoid), log-scale; |q . q'| >= 1 - rotation
TOL = {
    "ply": dict(color=1e-6, opacity=1e-6, log_scale=0.0, rotation=1e-6),
    "splat": dict(color=0.5 / 255 + 1e-6, opacity=0.5 / 255 + 1e-4, log_scale=1e-5, rotation=2e-4),
    "spz": dict(color=0.004, opacity=0.5 / 255 + 1e-4, log_scale=1 / 32 + 1e-4, rotation=2e-4),
    "compressed-ply": dict(color=0.004, opacity=0.5 / 255 + 1e-4, log_scale=0.01, rotation=2e-4),
}


@pytest.mark.parametrize("fmt,suffix", [("ply", ".ply"), ("splat", ".splat"), ("spz", ".spz"),
                                        ("compressed-ply", ".compressed.ply")])
def test_each_format_reads_back(tmp_path, fmt, suffix):
    a = grid_map()
    out = export_map(a, fmt, tmp_path / f"map{suffix}")
    b = read_map_file(out)   # our readers undo SPZ's RUB axes
    assert len(b["means"]) == len(a["means"])
    match = np.argsort(cell_ids(a["means"]))[cell_ids(b["means"])]   # read-back i <- map match[i]
    assert sorted(cell_ids(b["means"])) == list(range(SIDE ** 3)), "not one Gaussian per cell"
    tol = TOL[fmt]
    assert np.abs(b["means"] - a["means"][match]).max() < 1e-3
    assert np.abs(b["colors"] - a["colors"][match]).max() <= tol["color"]
    assert np.abs(sigmoid(b["logit_opacities"]) - sigmoid(a["logit_opacities"][match])).max() <= tol["opacity"]
    if fmt != "splat":   # .splat stores linear scales; those are compared as logs too
        assert b["log_scales"].shape[1] == 3
    log_b = np.broadcast_to(b["log_scales"], (len(match), 3))
    assert np.abs(log_b - a["log_scales"][match]).max() <= tol["log_scale"] + 1e-6
    dots = np.abs((normalised_quaternions(b["rotations"]) * normalised_quaternions(a["rotations"][match])).sum(1))
    assert dots.min() >= 1 - tol["rotation"]


def test_spz_file_is_in_rub_axes(tmp_path):
    """The file holds (x, -y, -z) and the rotation F R F (F = diag(1, -1, -1)), as Niantic's
    readers expect; gsply alone (no axis conversion) shows what is on disk."""
    import gsply

    a = grid_map(isotropic=False)
    export_map(a, "spz", tmp_path / "m.spz")
    raw = gsply.read_spz(tmp_path / "m.spz")
    order = spatial_order(a["means"])
    np.testing.assert_allclose(raw.means, a["means"][order] * [1, -1, -1], atol=1e-3)
    q = normalised_quaternions(a["rotations"][order]) * [1, 1, -1, -1]
    assert np.abs((normalised_quaternions(raw.quats) * q).sum(1)).min() > 1 - 2e-4
    assert not np.allclose(raw.means[:, 1], a["means"][order][:, 1], atol=0.1)


def test_spatial_order_makes_compact_chunks():
    a = grid_map()
    order = spatial_order(a["means"])
    assert sorted(order) == list(range(len(order)))
    chunks = a["means"][order].reshape(-1, CHUNK, 3)
    extent = np.ptp(chunks, axis=1).max()
    assert extent < 1.6, extent          # a 3 m cube in 16 chunks: boxes of 0.75 x 1.5 x 1.5 m
    assert np.ptp(a["means"][:CHUNK], axis=0).max() > 2.5   # in file order a chunk spans the cube


def test_compressed_ply_is_recognised_by_its_header(tmp_path):
    a = grid_map()
    export_map(a, "compressed-ply", tmp_path / "c.compressed.ply")
    write_ply(tmp_path / "p.ply", a)
    assert is_compressed_ply(tmp_path / "c.compressed.ply") and not is_compressed_ply(tmp_path / "p.ply")
    assert (tmp_path / "c.compressed.ply").stat().st_size < (tmp_path / "p.ply").stat().st_size / 4


@pytest.fixture()
def run_dir(tmp_path):
    write_ply(tmp_path / "run" / "map.ply", grid_map(isotropic=True))
    return tmp_path / "run"


def cli(args, capsys):
    code = splatam_main(["export", *map(str, args)])
    return code, capsys.readouterr()


@pytest.mark.parametrize("name,fmt", [("m.spz", "spz"), ("m.compressed.ply", "compressed-ply"),
                                      ("m.ply", "ply"), ("m.splat", "splat"), ("m.html", "html")])
def test_cli_takes_the_format_from_the_suffix(run_dir, capsys, name, fmt):
    code, out = cli([run_dir, "--out", run_dir / name], capsys)
    assert code == 0, out.err
    assert f"wrote 4,096 Gaussians to {run_dir / name} ({fmt}," in out.out
    if fmt != "html":
        assert len(read_map_file(run_dir / name)["means"]) == SIDE ** 3


def test_cli_accepts_a_map_file(run_dir, capsys):
    code, out = cli([run_dir / "map.ply", "--format", "spz", "--out", run_dir / "x.bin"], capsys)
    assert code == 0, out.err
    assert len(read_spz(run_dir / "x.bin")["means"]) == SIDE ** 3


@pytest.mark.parametrize("case", ["unknown format", "no suffix", "missing", "not a run", "out is a folder"])
def test_cli_errors_are_one_line(run_dir, tmp_path, capsys, case):
    empty, nope, obj = tmp_path / "empty", tmp_path / "nope", tmp_path / "m.xyz"   # (.obj and .glb name a mesh)
    empty.mkdir()
    args, message = {
        "unknown format": ([run_dir, "--format", "gltf", "--out", tmp_path / "m.gltf"],
                           "--format gltf: unknown export format; expected one of ply, splat, spz, compressed-ply, html, "
                           "colmap, nerfstudio, mesh"),
        "no suffix": ([run_dir, "--out", obj], f"{obj}: cannot tell the format from the suffix; pass --format"),
        "missing": ([nope, "--format", "spz", "--out", tmp_path / "m.spz"], f"{nope}: no such run folder or map file"),
        "not a run": ([empty, "--out", tmp_path / "m.spz"], f"{empty}: not a run folder (expected map.ply inside)"),
        "out is a folder": ([run_dir, "--format", "spz", "--out", empty], f"{empty}: is a folder; expected a file name"),
    }[case]
    code, out = cli(args, capsys)
    assert code == 2
    assert out.err.startswith("error: ") and message in out.err, out.err
    assert out.err.count("\n") == 1 and "Traceback" not in out.err
    assert not (tmp_path / "m.spz").exists() and not (tmp_path / "m.gltf").exists()


def test_failed_export_keeps_the_previous_file(tmp_path):
    good = export_map(grid_map(), "spz", tmp_path / "m.spz")
    before = good.read_bytes()
    far = grid_map()
    far["means"][0] = [1e4, 0.0, 0.0]   # beyond SPZ's 24-bit fixed point at 10 fractional bits
    with pytest.raises(InputError, match=re.escape("holds |x| < 8192 m")):
        export_map(far, "spz", good)
    assert good.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.spz"]   # no temporary left behind
    umask = os.umask(0)
    os.umask(umask)
    assert good.stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("name", ["bad.spz", "bad.compressed.ply"])
def test_unreadable_map_file_is_one_line(tmp_path, capsys, name):
    bad = tmp_path / name
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement chunk 9\nend_header\n" if "ply" in name
                    else b"not an spz file")
    code, out = cli([bad, "--format", "ply", "--out", tmp_path / "m.ply"], capsys)
    assert code == 2 and out.err.count("\n") == 1, out.err
    assert out.err.startswith(f"error: {bad}: not a readable ")


def test_empty_map_is_an_input_error(tmp_path):
    empty = {k: v[:0] for k, v in grid_map().items()}
    with pytest.raises(InputError, match="the map has no Gaussians; nothing to export"):
        export_map(empty, "spz", tmp_path / "m.spz")
    assert list(tmp_path.iterdir()) == []


def test_html_page_embeds_the_scene(tmp_path):
    page = export_map(grid_map(), "html", tmp_path / "m.html").read_text()
    assert page.startswith("<!") and "window.__VISER_EMBED_DATA__=" in page
    assert len(page) > 4096 * 32   # the scene is inlined (32 B per Gaussian, base64)


# ----------------------------------------------------------------------------- browser

CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
ARGS = ["--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
        "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]


def red_patch(n=5000):
    """A 1 m square of red splats 2 m in front of the world origin (the first camera)."""
    rng = np.random.default_rng(0)
    return dict(means=np.c_[rng.uniform(-0.5, 0.5, (n, 2)), 2 + rng.normal(0, 0.01, n)].astype(np.float32),
                colors=np.tile([[1.0, 0.1, 0.1]], (n, 1)).astype(np.float32),
                rotations=np.tile([[1.0, 0, 0, 0]], (n, 1)).astype(np.float32),
                logit_opacities=np.full(n, 3.0, np.float32),
                log_scales=np.full((n, 1), np.log(0.02), np.float32))


@pytest.mark.browser
@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed (apt-get install chromium)")
def test_html_page_shows_the_splats_offline(tmp_path):
    """The exported page, opened from file:// with every other request blocked, draws the map."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
    from PIL import Image

    page_path = export_map(red_patch(), "html", tmp_path / "map.html")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 800, "height": 600})
            blocked, errors = [], []
            local = ("file:", "data:", "blob:")
            page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(local)
                       else (blocked.append(route.request.url), route.abort()))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(page_path.as_uri())
            deadline, red = time.monotonic() + 90, 0
            while time.monotonic() < deadline:
                img = np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot())))
                red = int(((img[..., 0] > 180) & (img[..., 1] < 90) & (img[..., 2] < 90)).sum())
                if red > 2000:
                    break
                time.sleep(0.5)
            nodes = page.evaluate("() => Object.keys(window.__viserMutable?.nodeRefFromName ?? {})")
        finally:
            browser.close()
    assert red > 2000, f"only {red} red pixels: the splats did not appear"
    assert "/map" in nodes
    assert errors == [] and blocked == []
