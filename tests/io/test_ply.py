"""The 3DGS PLY writer/reader and the .splat layout (docs/formats.md, "Files written")."""

from __future__ import annotations

import numpy as np
import pytest

from splat_core.errors import InputError
from splat_core.io.ply import (PLY_PROPERTIES, SH_C0, SPLAT_DTYPE, read_ply, read_splat, write_ply,
                               write_splat)


def random_arrays(n=50, isotropic=True, seed=0):
    rng = np.random.default_rng(seed)
    return dict(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        colors=rng.uniform(0, 1, (n, 3)).astype(np.float32),
        rotations=rng.normal(size=(n, 4)).astype(np.float32),
        logit_opacities=rng.normal(size=n).astype(np.float32),
        log_scales=rng.uniform(-5, -1, (n, 1 if isotropic else 3)).astype(np.float32),
        birth_frame=rng.integers(0, 10, n),
    )


def header_of(path):
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode(), data[end:]


def test_ply_header_is_the_standard_3dgs_schema(tmp_path):
    a = random_arrays(7)
    write_ply(tmp_path / "m.ply", a)
    header, body = header_of(tmp_path / "m.ply")
    lines = header.strip().split("\n")
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 7"]
    assert lines[3:-1] == [f"property float {p}" for p in PLY_PROPERTIES]
    assert PLY_PROPERTIES == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                              "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert len(body) == 7 * 17 * 4
    table = np.frombuffer(body, dtype=np.dtype([(p, "<f4") for p in PLY_PROPERTIES]))
    np.testing.assert_allclose(table["f_dc_1"], (a["colors"][:, 1] - 0.5) / SH_C0, rtol=1e-6)
    np.testing.assert_array_equal(table["scale_2"], a["log_scales"][:, 0])   # isotropic tiled x3
    np.testing.assert_array_equal(table["opacity"], a["logit_opacities"])    # the logit
    np.testing.assert_array_equal(table["rot_0"], a["rotations"][:, 0])      # w first
    assert not table["nx"].any()


@pytest.mark.parametrize("isotropic", [True, False])
def test_ply_round_trip(tmp_path, isotropic):
    a = random_arrays(100, isotropic)
    write_ply(tmp_path / "m.ply", a)
    b = read_ply(tmp_path / "m.ply")
    for key in ("means", "rotations", "logit_opacities", "log_scales"):
        np.testing.assert_array_equal(b[key], a[key], err_msg=key)
    np.testing.assert_allclose(b["colors"], a["colors"], atol=1e-6)
    assert b["log_scales"].shape == a["log_scales"].shape
    assert b["birth_frame"].shape == (100,)


def test_ply_write_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "m.ply"
    write_ply(path, random_arrays(5))
    good = path.read_bytes()
    bad = random_arrays(5)
    bad["colors"] = np.zeros((4, 3))   # inconsistent N: fails before anything is written
    with pytest.raises(ValueError):
        write_ply(path, bad)
    assert path.read_bytes() == good
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


def test_read_ply_with_sh_rest_extra_properties_and_ascii(tmp_path):
    """Files from other 3DGS tools: f_rest_*, extra properties, double types, an ascii body."""
    n = 4
    rng = np.random.default_rng(1)
    props = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + \
        [f"f_rest_{i}" for i in range(45)] + ["opacity", "scale_0", "scale_1", "scale_2",
                                              "rot_0", "rot_1", "rot_2", "rot_3", "segment"]
    values = rng.normal(size=(n, len(props)))
    dtype = np.dtype([(p, "<f8" if p == "x" else "<f4") for p in props[:-1]] + [("segment", "u1")])
    table = np.zeros(n, dtype)
    for i, p in enumerate(props):
        table[p] = np.abs(values[:, i]) if p == "segment" else values[:, i]
    head = "ply\nformat binary_little_endian 1.0\ncomment from another tool\nelement vertex 4\n" + \
        "".join(f"property {'double' if p == 'x' else 'uchar' if p == 'segment' else 'float'} {p}\n"
                for p in props) + "end_header\n"
    (tmp_path / "b.ply").write_bytes(head.encode() + table.tobytes())
    b = read_ply(tmp_path / "b.ply")
    np.testing.assert_allclose(b["means"][:, 0], values[:, 0], rtol=1e-6)
    np.testing.assert_allclose(b["colors"][:, 2], 0.5 + SH_C0 * values[:, 8].astype(np.float32), rtol=1e-5)
    assert b["log_scales"].shape == (n, 3)

    ascii_head = "ply\nformat ascii 1.0\nelement vertex 2\n" + \
        "".join(f"property float {p}\n" for p in PLY_PROPERTIES) + "end_header\n"
    rows = "\n".join(" ".join(str(float(v)) for v in range(i, i + 17)) for i in range(2))
    (tmp_path / "a.ply").write_text(ascii_head + rows + "\n")
    a = read_ply(tmp_path / "a.ply")
    np.testing.assert_array_equal(a["means"][1], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(a["rotations"][0], [13.0, 14.0, 15.0, 16.0])


@pytest.mark.parametrize("content, message", [
    (b"hello", "not a PLY"),
    (b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n", "not supported"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n" + b"\0" * 24, "f_dc_0"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n" +
     b"".join(f"property float {p}\n".encode() for p in PLY_PROPERTIES) + b"end_header\n" + b"\0" * 10,
     "truncated"),
    (b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
     "list property"),
])
def test_read_ply_errors_name_the_file(tmp_path, content, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(InputError, match=message) as e:
        read_ply(path)
    assert str(path) in str(e.value)


def test_splat_layout_and_order(tmp_path):
    a = random_arrays(64, isotropic=False)
    write_splat(tmp_path / "m.splat", a)
    raw = (tmp_path / "m.splat").read_bytes()
    assert len(raw) == 64 * 32
    t = np.frombuffer(raw, SPLAT_DTYPE)
    key = np.exp(a["log_scales"].astype(np.float64)).prod(1) / (1 + np.exp(-a["logit_opacities"].astype(np.float64)))
    order = np.argsort(-key, kind="stable")
    assert np.all(np.diff(key[order]) <= 0)   # descending scale-volume x opacity
    np.testing.assert_allclose(t["position"], a["means"][order])
    np.testing.assert_allclose(t["scale"], np.exp(a["log_scales"][order]), rtol=1e-6)
    q = a["rotations"][order] / np.linalg.norm(a["rotations"][order], axis=1, keepdims=True)
    assert np.abs(np.clip(q * 128 + 128, 0, 255) - t["rotation"]).max() <= 0.51
    alpha = 255 / (1 + np.exp(-a["logit_opacities"][order]))
    assert np.abs(t["rgba"][:, 3] - alpha).max() <= 0.51
    b = read_splat(tmp_path / "m.splat")
    np.testing.assert_allclose(b["means"], a["means"][order])
    np.testing.assert_allclose(b["colors"], np.clip(a["colors"][order], 0, 1), atol=0.5 / 255 + 1e-6)
