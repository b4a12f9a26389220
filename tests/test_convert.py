"""`pixie convert` and pixie_gs.convert: real meshes written with trimesh, real .ply files read back."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from pixie_gs.cli.main import main
from pixie_gs.convert import bilinear_texture_lookup, load_mesh, mesh_to_splat, points_inside
from pixie_gs.errors import InputError
from pixie_gs.splat import quat_to_rotmat, read_splat

# 2×2 blocks of 4×4 texels each: image rows run top (v = 1) to bottom (v = 0).
BLOCK_COLORS = np.array([[[230, 20, 20], [20, 200, 40]],     # top-left red, top-right green
                         [[30, 40, 220], [240, 220, 30]]],   # bottom-left blue, bottom-right yellow
                        np.uint8)
TEXELS_PER_BLOCK = 4


def block_texture() -> Image.Image:
    return Image.fromarray(np.kron(BLOCK_COLORS, np.ones((TEXELS_PER_BLOCK, TEXELS_PER_BLOCK, 1), np.uint8)))


def textured_quad(factor=(255, 255, 255, 255)) -> trimesh.Trimesh:
    """Unit quad in z = 0 with uv = (x, y), textured with the four colour blocks."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=block_texture(), baseColorFactor=factor)
    visual = trimesh.visual.TextureVisuals(uv=vertices[:, :2].copy(), material=material)
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], visual=visual, process=False)


# A rigid placement of the quad inside the glTF scene (rotation about x by 90°, then a shift).
PLACEMENT = trimesh.transformations.concatenate_matrices(
    trimesh.transformations.translation_matrix([0.3, -2.0, 0.5]),
    trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))


def write_textured_glb(path, factor=(255, 255, 255, 255)) -> None:
    scene = trimesh.Scene()
    scene.add_geometry(textured_quad(factor), transform=PLACEMENT)
    scene.export(str(path))


def expected_block_colors(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(block colour (n,3) in [0,1], mask of samples > 0.6 texel from any block edge).

    Bilinear lookup blends the two nearest texel centres, so only samples within half a texel of a
    block edge (or of the image border, which wraps) may mix colours.
    """
    col = (uv[:, 0] >= 0.5).astype(int)
    row = (uv[:, 1] < 0.5).astype(int)  # v < 0.5 is the image's bottom half
    texels = uv * 2 * TEXELS_PER_BLOCK
    to_edge = np.minimum(np.abs(texels - TEXELS_PER_BLOCK), np.minimum(texels, 2 * TEXELS_PER_BLOCK - texels))
    interior = np.all(to_edge > 0.6, axis=1)
    return BLOCK_COLORS[row, col] / 255.0, interior


def run_cli(argv, capsys) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


def test_textured_gltf_colours_match_texels_and_lie_on_surface(tmp_path, capsys):
    mesh_path, out = tmp_path / "quad.glb", tmp_path / "quad.ply"
    write_textured_glb(mesh_path)
    code, _ = run_cli(["convert", str(mesh_path), str(out), "--count", "4000", "--seed", "3", "-q"], capsys)
    assert code == 0
    cloud = read_splat(out)
    assert len(cloud) == 4000 and cloud.sh_degree == 0 and cloud.sh_rest.shape == (4000, 0)
    assert cloud.property_order[:6] == ["x", "y", "z", "nx", "ny", "nz"]
    # map centres back into the quad's own frame: its plane is z = 0 and uv = (x, y)
    inverse = np.linalg.inv(PLACEMENT)
    local = cloud.means.astype(np.float64) @ inverse[:3, :3].T + inverse[:3, 3]
    assert np.abs(local[:, 2]).max() < 1e-5  # on the surface (size 1)
    assert local[:, :2].min() >= -1e-6 and local[:, :2].max() <= 1 + 1e-6
    expected, interior = expected_block_colors(local[:, :2])
    assert interior.sum() > 1000
    np.testing.assert_allclose(cloud.rgb()[interior], expected[interior], atol=1.0 / 255)
    # all four blocks are represented
    assert len(np.unique(np.round(cloud.rgb()[interior] * 255), axis=0)) == 4
    # flat discs: the smallest axis is the placed quad's normal (local z -> world -y after rotation)
    assert np.allclose(np.abs(cloud.extras["ny"]), 1.0, atol=1e-6)
    R = quat_to_rotmat(cloud.rotations)
    np.testing.assert_allclose(np.abs(R[:, 1, 2]), 1.0, atol=1e-5)
    assert np.all(cloud.scales[:, 2] < 0.2 * cloud.scales[:, 0])


def test_scene_parts_keep_their_own_textures(tmp_path):
    """Two quads with different textures in one glTF scene: each sample takes its own part's texels."""
    upper = textured_quad()
    mirrored = Image.fromarray(np.kron(BLOCK_COLORS[::-1, ::-1], np.ones((TEXELS_PER_BLOCK,) * 2 + (1,), np.uint8)))
    upper.visual.material = trimesh.visual.material.PBRMaterial(baseColorTexture=mirrored)
    scene = trimesh.Scene()
    scene.add_geometry(textured_quad())
    scene.add_geometry(upper, transform=trimesh.transformations.translation_matrix([0, 0, 1]))
    scene.export(str(tmp_path / "two.glb"))
    cloud = mesh_to_splat(load_mesh(tmp_path / "two.glb"), 3000, np.random.default_rng(0))
    for height, uv_of in ((0.0, lambda xy: xy), (1.0, lambda xy: 1.0 - xy)):
        sel = np.abs(cloud.means[:, 2] - height) < 1e-6
        expected, interior = expected_block_colors(uv_of(cloud.means[sel][:, :2].astype(np.float64)))
        assert interior.sum() > 500
        np.testing.assert_allclose(cloud.rgb()[sel][interior], expected[interior], atol=1.0 / 255)


@pytest.mark.parametrize("suffix", [".obj", ".gltf"])
def test_textured_obj_and_gltf_with_side_files(tmp_path, suffix):
    """OBJ (+ .mtl + .png, simple material) and text glTF (+ .bin buffers) give the same texels."""
    quad = textured_quad()
    if suffix == ".obj":
        quad.visual.material = trimesh.visual.material.SimpleMaterial(image=block_texture())
    trimesh.Scene([quad]).export(str(tmp_path / f"quad{suffix}"))
    cloud = mesh_to_splat(load_mesh(tmp_path / f"quad{suffix}"), 2000, np.random.default_rng(0))
    assert np.abs(cloud.means[:, 2]).max() < 1e-6
    expected, interior = expected_block_colors(cloud.means[:, :2].astype(np.float64))
    np.testing.assert_allclose(cloud.rgb()[interior], expected[interior], atol=1.0 / 255)


def test_bilinear_lookup_and_base_colour_factor(tmp_path):
    image = np.asarray(block_texture(), np.float64) / 255.0
    # texel centre of the top-left texel is (u, v) = (0.5/8, 1 − 0.5/8); halfway between two texels blends
    np.testing.assert_allclose(bilinear_texture_lookup(image, np.array([[0.5 / 8, 1 - 0.5 / 8]])),
                               [BLOCK_COLORS[0, 0] / 255.0])
    midway = bilinear_texture_lookup(image, np.array([[0.5, 0.75]]))  # between red and green blocks
    np.testing.assert_allclose(midway[0], (BLOCK_COLORS[0, 0] + BLOCK_COLORS[0, 1]) / 2 / 255.0)
    path = tmp_path / "half_red.glb"
    write_textured_glb(path, factor=(128, 255, 255, 255))
    mesh = load_mesh(path)
    cloud = mesh_to_splat(mesh, 2000, np.random.default_rng(0))
    inverse = np.linalg.inv(PLACEMENT)
    uv = (cloud.means.astype(np.float64) @ inverse[:3, :3].T + inverse[:3, 3])[:, :2]
    expected, interior = expected_block_colors(uv)
    expected[:, 0] *= 128 / 255
    np.testing.assert_allclose(cloud.rgb()[interior], expected[interior], atol=1.0 / 255)


def test_vertex_and_face_colours_and_fixed_colour(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    heights = (box.vertices[:, 2] + 1.0) / 2.0  # 0 at the bottom, 1 at the top
    box.visual.vertex_colors = np.stack([heights * 255, np.zeros_like(heights), 255 - heights * 255,
                                         np.full_like(heights, 255)], axis=1).astype(np.uint8)
    path = tmp_path / "gradient.ply"
    box.export(str(path))
    cloud = mesh_to_splat(load_mesh(path), 3000, np.random.default_rng(1))
    t = (cloud.means[:, 2] + 1.0) / 2.0  # vertex colours interpolate linearly along each face
    np.testing.assert_allclose(cloud.rgb()[:, 0], t, atol=1.5 / 255)
    np.testing.assert_allclose(cloud.rgb()[:, 2], 1 - t, atol=1.5 / 255)

    faces = trimesh.creation.box()
    faces.visual.face_colors = np.where(faces.face_normals[:, 2:3] > 0.5, [10, 250, 10, 255], [250, 10, 10, 255])
    cloud = mesh_to_splat(faces, 2000, np.random.default_rng(2))
    top = cloud.means[:, 2] > 0.5 - 1e-6
    np.testing.assert_allclose(cloud.rgb()[top], np.tile([10 / 255, 250 / 255, 10 / 255], (top.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(cloud.rgb()[~top][:, 0], 250 / 255, atol=1e-6)

    fixed = mesh_to_splat(faces, 5000, np.random.default_rng(2), rgb=np.array([0.2, 0.4, 0.6]), color_noise=0.05)
    jitter = fixed.rgb() - np.array([0.2, 0.4, 0.6], np.float32)
    assert abs(jitter.mean()) < 0.003 and 0.045 < jitter.std() < 0.055


def test_box_surface_distance_scales_and_normals():
    size = 3.0
    box = trimesh.creation.box(extents=(size, size, size))
    cloud = mesh_to_splat(box, 6000, np.random.default_rng(4), normal_scale_ratio=0.1, opacity=0.8)
    half = size / 2
    on_face = np.abs(np.abs(cloud.means).max(axis=1) - half)
    assert on_face.max() < 1e-5 * size  # every centre lies on the box surface
    spacing = np.sqrt(6 * size * size / 6000)
    np.testing.assert_allclose(cloud.scales[:, :2], 0.7 * spacing, rtol=1e-5)
    np.testing.assert_allclose(cloud.scales[:, 2], 0.07 * spacing, rtol=1e-5)
    np.testing.assert_allclose(cloud.opacities, 0.8, atol=1e-6)
    normals = np.stack([cloud.extras[k] for k in ("nx", "ny", "nz")], axis=1)
    outward = np.sign(cloud.means) * (np.abs(cloud.means) >= half - 1e-5)
    np.testing.assert_allclose(normals, outward, atol=1e-6)  # outward face normals
    np.testing.assert_allclose(quat_to_rotmat(cloud.rotations)[:, :, 2], normals, atol=1e-5)
    # area weighting: each of the 6 equal faces gets ~1/6 of the samples
    counts = np.bincount(np.argmax(np.abs(cloud.means), axis=1) * 2 + (cloud.means.max(axis=1) >= half - 1e-5))
    assert np.all(np.abs(counts / 6000 - 1 / 6) < 0.03)


def test_fill_puts_gaussians_inside_a_watertight_box(tmp_path, capsys):
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    path, out = tmp_path / "box.stl", tmp_path / "box.ply"
    box.export(str(path))
    preview = tmp_path / "box.png"
    code, _ = run_cli(["convert", str(path), str(out), "--count", "2000", "--fill", "--fill-count", "1500",
                       "--preview", str(preview), "-q"], capsys)
    assert code == 0
    picture = np.asarray(Image.open(preview).convert("RGB"))
    assert picture.shape == (256 + 16, 4 * 256, 3)
    grey = np.all(picture == round(0.7 * 255), axis=2)  # the uncoloured mesh's default grey
    assert 0.05 < grey[16:, :256].mean() < 0.9
    cloud = read_splat(out)
    assert len(cloud) == 3500
    inner = cloud.means[2000:]
    half = np.array([0.5, 1.0, 0.25])
    assert np.all(np.abs(inner) < half)
    # roughly uniform in the volume: each octant holds ~1/8
    octant = (inner > 0).astype(int) @ [1, 2, 4]
    assert np.all(np.abs(np.bincount(octant, minlength=8) / 1500 - 0.125) < 0.04)
    np.testing.assert_allclose(cloud.scales[2000:, 0], cloud.scales[2000:, 2])  # isotropic
    assert np.all(cloud.extras["nx"][2000:] == 0)

    # interior Gaussians take the colour of the nearest surface sample: green just under a green top
    coloured = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    coloured.visual.face_colors = np.where(coloured.face_normals[:, 2:3] > 0.5, [0, 255, 0, 255], [255, 0, 0, 255])
    cloud = mesh_to_splat(coloured, 4000, np.random.default_rng(6), fill=True, n_fill=4000)
    inner, inner_rgb = cloud.means[4000:], cloud.rgb()[4000:]
    under_top = (inner[:, 2] > 0.45) & np.all(np.abs(inner[:, :2]) < 0.3, axis=1)
    near_side = (np.abs(inner[:, 0]) > 0.45) & (np.abs(inner[:, 2]) < 0.3)
    assert under_top.sum() > 10 and near_side.sum() > 10
    assert np.all(inner_rgb[under_top] == [0, 1, 0]) and np.all(inner_rgb[near_side] == [1, 0, 0])

    open_quad = textured_quad()
    with pytest.raises(InputError, match="watertight"):
        mesh_to_splat(open_quad, 100, np.random.default_rng(0), fill=True)


def test_points_inside_matches_winding_number_on_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    points = np.random.default_rng(5).uniform(-1.2, 1.2, (2000, 3))
    tri = sphere.vertices[sphere.faces][None] - points[:, None, None, :]
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + (a * b).sum(2) * lc + (b * c).sum(2) * la + (c * a).sum(2) * lb
    winding = np.arctan2(det, den).sum(axis=1) / (2 * np.pi)
    assert np.array_equal(points_inside(sphere, points), winding > 0.5)


def test_same_seed_gives_identical_bytes(tmp_path, capsys):
    mesh_path = tmp_path / "quad.glb"
    write_textured_glb(mesh_path)
    outs = [tmp_path / "a.ply", tmp_path / "b.ply", tmp_path / "c.ply"]
    for out, seed in zip(outs, ["7", "7", "8"]):
        assert run_cli(["convert", str(mesh_path), str(out), "--count", "500", "--seed", seed, "-q"], capsys)[0] == 0
    assert outs[0].read_bytes() == outs[1].read_bytes()
    assert outs[0].read_bytes() != outs[2].read_bytes()


def glb_with_index_out_of_range() -> bytes:
    """trimesh's GLB of an icosphere (42 vertices) with its first triangle's first index set to 714."""
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    glb = sphere.export(file_type="glb")
    at = glb.find(np.asarray(sphere.faces).astype("<u4").tobytes())
    assert at > 0
    return glb[:at] + np.uint32(714).tobytes() + glb[at + 4:]


@pytest.mark.parametrize("name, content, message", [
    ("broken.glb", b"glTF\x02\x00\x00\x00garbage-not-a-real-binary-gltf", "cannot read mesh"),
    # found by mutation fuzzing (docs/benchmarks.md, stop 53): trimesh reads these, then fails on first use
    ("index.glb", glb_with_index_out_of_range(), "triangle 0 refers to vertex 714, but the mesh has 42 vertices"),
    ("index.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
     "triangle 0 refers to vertex 7, but the mesh has 3 vertices"),
    ("flat.obj", b"v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "vertex positions have shape (3, 2), not (N, 3)"),
    ("points.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                   b"property float z\nend_header\n0 0 0\n1 1 1\n", "no triangle faces"),
    ("model.xyz", b"0 0 0\n", "unsupported mesh type"),
    ("missing.obj", None, "no such file"),
], ids=lambda v: v if isinstance(v, str) and "." in v and " " not in v else "")
def test_bad_mesh_file_gives_one_line_error_and_no_output(tmp_path, capsys, name, content, message):
    path, out = tmp_path / name, tmp_path / "out.ply"
    if content is not None:
        path.write_bytes(content)
    code, err = run_cli(["convert", str(path), str(out), "-q"], capsys)
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and name in lines[0]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ([name] if content is not None else [])


# ---------------------------------------------------------------- splat → splat between formats
GUITAR = __import__("pathlib").Path(__file__).parent / "data" / "guitar_slice.compressed.ply"


def _splat_with_extras(n: int = 600):
    from pixie_gs.splat import SplatCloud

    rng = np.random.default_rng(4)
    cloud = SplatCloud.from_arrays(rng.uniform(-1, 1, (n, 3)), log_scales=rng.uniform(-5, -2, (n, 3)),
                                   rotations=rng.normal(size=(n, 4)), opacity_logits=rng.uniform(-4, 4, n),
                                   rgb=rng.uniform(0, 1, (n, 3)), sh_rest=rng.uniform(-0.5, 0.5, (n, 45)))
    cloud.set_materials(rng.integers(0, 3, n), np.full(n, 1e6), np.full(n, 0.3), np.full(n, 400))
    return cloud


def test_convert_between_splat_formats_by_output_name(tmp_path, capsys):
    src = tmp_path / "scene.ply"
    _splat_with_extras().write(src)
    before = src.read_bytes()
    for name, fmt in [("scene.splat", "splat"), ("scene.spz", "spz"), ("scene.compressed.ply", "compressed_ply")]:
        code, err = run_cli(["convert", str(src), str(tmp_path / name)], capsys)
        assert code == 0, err
        back = read_splat(tmp_path / name)
        assert back.source_format == fmt and len(back) == 600
        lossy = [line for line in err.splitlines() if "lossy" in line]
        assert len(lossy) == 1 and "4 extra properties (material_id, E, nu, density) dropped" in lossy[0], err
    assert src.read_bytes() == before  # the input is never touched
    # .spz → INRIA PLY: nothing lost on the way out, SH degree kept
    code, err = run_cli(["convert", str(tmp_path / "scene.spz"), str(tmp_path / "back.ply")], capsys)
    assert code == 0 and "lossy" not in err
    ply = read_splat(tmp_path / "back.ply")
    assert ply.source_format == "inria_ply" and ply.sh_degree == 3
    np.testing.assert_allclose(ply.means, read_splat(src).means, atol=0.5 / 4096 + 1e-6)


def test_convert_splat_message_names_dropped_sh(tmp_path, capsys):
    src = tmp_path / "s.ply"
    _splat_with_extras().write(src)
    code, err = run_cli(["convert", str(src), str(tmp_path / "s.splat")], capsys)
    assert code == 0
    line = next(l for l in err.splitlines() if "lossy" in l)
    assert ".splat keeps SH degree 0 only" in line and "45 f_rest" in line


def test_convert_format_flag_overrides_the_name_and_real_file_converts(tmp_path, capsys):
    out = tmp_path / "guitar.ply"
    code, err = run_cli(["convert", str(GUITAR), str(out), "--format", "splat", "-q"], capsys)
    assert code == 0
    assert out.stat().st_size == 768 * 32  # a .splat in a .ply name, as asked
    got, ref = read_splat(out), read_splat(GUITAR)
    assert got.source_format == "splat"
    np.testing.assert_array_equal(got.means, ref.means)
    assert np.abs(got.opacities - ref.opacities).max() <= 0.5 / 255 + 1e-6


def test_convert_refuses_mesh_flags_for_splat_input_and_bad_splats(tmp_path, capsys):
    src = tmp_path / "s.ply"
    _splat_with_extras(50).write(src)
    code, err = run_cli(["convert", str(src), str(tmp_path / "o.spz"), "--fill"], capsys)
    assert code == 1 and "apply to mesh input" in err and not (tmp_path / "o.spz").exists()
    bad = tmp_path / "bad.spz"
    bad.write_bytes(b"\x1f\x8b" + b"\x00" * 30)
    code, err = run_cli(["convert", str(bad), str(tmp_path / "o.ply")], capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1 and "gzip" in err
    assert not (tmp_path / "o.ply").exists()


def _glb_with_extensions(path, used: list[str], required: list[str]) -> None:
    """A real box .glb (trimesh's export) whose JSON chunk is rewritten to list glTF extensions."""
    import json
    import struct

    data = trimesh.creation.box().export(file_type="glb")
    json_len = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + json_len])
    doc["extensionsUsed"] = used
    if required:
        doc["extensionsRequired"] = required
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + json_len:]
    body = struct.pack("<I4s", len(text), b"JSON") + text + rest
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)


@pytest.mark.parametrize("extension", ["KHR_draco_mesh_compression", "EXT_meshopt_compression"])
def test_compressed_gltf_geometry_is_named_not_called_degenerate(tmp_path, capsys, extension):
    """Sketchfab and PlayCanvas ship Draco-compressed .glb files (the chess board in
    benchmarks/real_holdout); trimesh reads their geometry as degenerate triangles. The error must name the
    compression, not the "zero surface area" trimesh's reading implies, and write nothing."""
    mesh_path, out = tmp_path / "chess.glb", tmp_path / "out.ply"
    _glb_with_extensions(mesh_path, [extension], [extension])
    before = mesh_path.read_bytes()
    code, err = run_cli(["convert", str(mesh_path), str(out), "-q"], capsys)
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1
    assert "chess.glb" in lines[0] and extension in lines[0] and "zero surface" not in lines[0]
    assert not out.exists() and mesh_path.read_bytes() == before


def test_gltf_that_only_uses_an_extension_still_converts(tmp_path, capsys):
    """A file may list a compression in extensionsUsed while keeping plain geometry as its fallback: that reads."""
    mesh_path, out = tmp_path / "box.glb", tmp_path / "out.ply"
    _glb_with_extensions(mesh_path, ["KHR_draco_mesh_compression"], [])
    code, _ = run_cli(["convert", str(mesh_path), str(out), "--count", "300", "-q"], capsys)
    assert code == 0 and len(read_splat(out)) == 300
