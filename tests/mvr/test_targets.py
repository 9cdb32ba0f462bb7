"""Targets: built-in shapes, mesh files (formats and bad files), normalisation, target images."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from mvr import SHAPES, Target, load_mesh, make_target, normalise_mesh, shape_mesh
from mvr.reconstruct import default_scene
from renderer import Cameras, shade_lambert


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_builtin_shapes_are_closed_with_their_genus(name):
    shape = SHAPES[name]
    # The meshed region holds the whole shape: the function is positive on its faces.
    lo, hi = np.array(shape.bounds_min), np.array(shape.bounds_max)
    axes = [torch.linspace(float(lo[a]), float(hi[a]), 40, dtype=torch.float64) for a in range(3)]
    f = shape.fn(torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1))
    faces = torch.cat([f[[0, -1]].ravel(), f[:, [0, -1]].ravel(), f[:, :, [0, -1]].ravel()])
    assert faces.min() > 0
    mesh = shape_mesh(name, 64)
    assert mesh.is_watertight and mesh.volume > 0
    assert (2 - mesh.euler_number) // 2 == shape.genus
    # Vertices were projected onto the zero set.
    assert shape.fn(torch.from_numpy(mesh.vertices)).abs().max() < 1e-3


def test_normalisation_centres_and_scales():
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    box.apply_translation((3.0, -1.0, 2.0))
    out, scale = normalise_mesh(box, 1.6)
    np.testing.assert_allclose(out.bounds, [[-0.8, -0.4, -0.2], [0.8, 0.4, 0.2]], atol=1e-12)
    assert scale == pytest.approx(0.8)
    assert box.bounds[0, 0] == pytest.approx(2.0)  # the input is not modified


def test_make_target_builtin_and_file(tmp_path):
    t = make_target("torus", extent=1.2, mesh_resolution=64)
    assert isinstance(t, Target) and t.source == "builtin:torus"
    assert (t.mesh.bounds[1] - t.mesh.bounds[0]).max() == pytest.approx(1.2)
    path = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=3.0).export(path)
    t2 = make_target(str(path), extent=1.0)
    assert t2.name == "ball" and t2.diagonal == pytest.approx(np.sqrt(3.0), rel=1e-3)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off", ".stl", ".glb"])
def test_mesh_formats(tmp_path, suffix):
    path = tmp_path / f"shape{suffix}"
    trimesh.creation.icosphere(subdivisions=2).export(path)
    mesh = load_mesh(path)
    assert mesh.is_watertight and mesh.volume > 0


def test_inverted_mesh_is_turned_outwards(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.invert()
    path = tmp_path / "inside_out.ply"
    mesh.export(path)
    assert load_mesh(path).volume > 0


def test_bad_mesh_files(tmp_path):
    missing = tmp_path / "nothing.obj"
    with pytest.raises(FileNotFoundError, match="nothing.obj"):
        make_target(str(missing))
    weird = tmp_path / "mesh.xyz"
    weird.write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"mesh\.xyz.*unsupported format"):
        make_target(str(weird))
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ValueError, match="empty.obj"):
        make_target(str(empty))
    open_mesh = trimesh.creation.icosphere(subdivisions=2)
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) > 3)
    path = tmp_path / "open.ply"
    open_mesh.export(path)
    with pytest.raises(ValueError, match=r"open\.ply.*not watertight"):
        make_target(str(path))
    with pytest.raises(ValueError, match=r"open\.ply.*6 boundary edges.*max_hole_edges=6 close its holes \(now 5\)"):
        make_target(str(path), max_hole_edges=5)
    with pytest.raises(ValueError, match=r"open\.ply.*still open after filling its 6 boundary edges"):
        make_target(str(path), max_hole_edges=6)  # a hexagonal hole: fill_holes closes triangles and quads
    one_face = trimesh.creation.icosphere(subdivisions=2)
    one_face.update_faces(np.arange(len(one_face.faces)) > 0)
    one_face.export(tmp_path / "one_face.ply")
    closed = make_target(str(tmp_path / "one_face.ply"), max_hole_edges=3)
    assert closed.holes_closed == 3 and closed.mesh.is_watertight and closed.mesh.volume > 0
    assert make_target("sphere", mesh_resolution=32, max_hole_edges=3).holes_closed == 0
    garbage = tmp_path / "garbage.off"
    garbage.write_bytes(b"\x00\x01 not a mesh")
    with pytest.raises(ValueError, match="garbage.off"):
        make_target(str(garbage))
    folder = tmp_path / "folder.obj"
    folder.mkdir()
    with pytest.raises(ValueError, match=r"folder\.obj.*is a folder"):
        make_target(str(folder))


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off", ".stl", ".glb"])
def test_zero_byte_mesh_files_are_called_empty(tmp_path, suffix):
    path = tmp_path / f"nothing{suffix}"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=rf"nothing\{suffix}.*empty"):
        load_mesh(path)


def test_bad_target_specs():
    with pytest.raises(ValueError, match="built-in shape"):
        make_target("tourus")
    with pytest.raises(TypeError, match="target"):
        make_target(3)
    with pytest.raises(ValueError, match="normals"):
        make_target("sphere", normals="flat", mesh_resolution=32)


def test_target_images_of_a_sphere_match_analytic_shading():
    """Mask and shading of a finely meshed sphere equal the exact sphere's, away from its edge."""
    target = make_target("sphere", extent=1.0, mesh_resolution=128)  # radius 0.5
    scene = default_scene()
    cams = Cameras.cube_rig(3.0, fov_deg=40, image_size=32)[[0, 6, 18]]
    views = target.render(cams, scene)
    assert views.images.shape == (3, 32, 32, 1) and views.masks.shape == (3, 32, 32)
    o, d = cams.to(dtype=torch.float64).rays()
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.25)
    away = disc.abs() > 0.02
    assert torch.equal(views.masks[away], (disc > 0)[away])
    t = -b - disc.clamp(min=0).sqrt()
    p = o + t[..., None] * d
    hit = (disc > 0.02)
    n = p[hit] / p[hit].norm(dim=-1, keepdim=True)
    eyes = cams.eye.double()[:, None, None, :].expand_as(p)[hit]
    expected = shade_lambert(n, p[hit], eyes, scene)
    np.testing.assert_allclose(views.images[hit].double().numpy(), expected.numpy(), atol=5e-3)
    assert (views.images[~views.masks] == 0).all()
