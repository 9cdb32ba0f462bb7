"""Reconstruction targets: a watertight mesh, normalised into the grid's box, and its images. A
target is a mesh file (.obj, .ply, .off, .stl, .glb, read by trimesh) or a built-in shape of
``mvr.shapes`` (meshed finely by marching cubes). Either way it is centred on the origin and scaled
so that the longest side of its bounding box is ``extent`` (world units). The target images come
from the mesh itself: rays through the pixel centres of our cameras are cast against its triangles
(``sdfcommon.numerics.raycast.mesh_caster``: Embree where it installs) and the hits are shaded by
``renderer.shade_lambert`` with the same scene (lights, ambient, albedo, background) the optimiser
renders with. The optimiser never sees an image made by its own renderer. Normals for the shading:
``"smooth"`` (default) interpolates the mesh's vertex normals with the barycentric weights of the
hit, the right choice for meshes that approximate smooth surfaces (our renderer's normals are
themselves smooth: interpolated finite differences); ``"face"`` uses each triangle's own normal,
right for meshes with sharp, flat facets. A mesh file with a few small holes (a scan) can be
closed on request (``close_small_holes``, ``target_settings.max_hole_edges``); without that request
a mesh that is not watertight is refused.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
import trimesh

from renderer import Cameras, Scene, shade_lambert
from sdfcommon.numerics.meshing import sdf_to_mesh
from sdfcommon.numerics.raycast import RayCaster, mesh_caster
from sdfcommon.tooling.checks import check_int, check_positive

from .shapes import SHAPES

log = logging.getLogger(__name__)

MESH_FORMATS = (".obj", ".ply", ".off", ".stl", ".glb")
NORMAL_MODES = ("smooth", "face")


@dataclass(frozen=True)
class TargetImages:
    """Target views rendered from the mesh.

    Attributes:
        images: (V, H, W, C) float32 shaded images (the scene's background where rays miss).
        masks: (V, H, W) bool, rays that hit the mesh.
    """

    images: torch.Tensor
    masks: torch.Tensor


class Target:
    """A watertight, outward-facing mesh normalised into the reconstruction's box.

    Attributes:
        name: the built-in shape's name or the file's stem.
        source: "builtin:<name>" or the file's path.
        mesh: trimesh.Trimesh in world coordinates (centred, longest bbox side ``extent``).
        scale: the factor applied to the source's coordinates (after centring).
        normals: "smooth" or "face", how hits are shaded.
        holes_closed: boundary edges of the mesh file's holes closed when it was read (0: none).
    """

    def __init__(self, name: str, source: str, mesh: trimesh.Trimesh, scale: float, normals: str = "smooth",
                 holes_closed: int = 0):
        if normals not in NORMAL_MODES:
            raise ValueError(f"normals must be one of {NORMAL_MODES}, got {normals!r}")
        self.name = name
        self.source = source
        self.mesh = mesh
        self.scale = float(scale)
        self.normals = normals
        self.holes_closed = int(holes_closed)
        self._caster: Optional[RayCaster] = None

    @property
    def diagonal(self) -> float:
        """Length of the diagonal of the mesh's axis-aligned bounding box (world units)."""
        lo, hi = self.mesh.bounds
        return float(np.linalg.norm(hi - lo))

    def render(self, cameras: Cameras, scene: Scene) -> TargetImages:
        """Ray-casts the mesh from ``cameras`` and shades the hits with ``scene``.

        Returns:
            TargetImages with (V, H, W, C) images, C = ``scene.channels``, and (V, H, W) masks.
        """
        if self._caster is None:
            self._caster = mesh_caster(self.mesh.vertices, self.mesh.faces)
        cams = cameras.to(dtype=torch.float64, device="cpu")
        origins, directions = cams.rays()
        v, h, w, _ = directions.shape
        o = origins.reshape(-1, 3).numpy()
        d = directions.reshape(-1, 3).numpy()
        hits = self._caster.first_hits(o, d)
        idx = np.nonzero(hits.hit)[0]
        faces = hits.face[idx]
        if self.normals == "smooth":
            vn = np.asarray(self.mesh.vertex_normals)[self.mesh.faces[faces]]  # (K, 3 vertices, 3)
            n = (hits.barycentric[idx, :, None] * vn).sum(axis=1)
        else:
            n = np.asarray(self.mesh.face_normals)[faces]
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        points = o[idx] + hits.t[idx, None] * d[idx]
        eyes = cams.eye.numpy()[idx // (h * w)]
        rgb = shade_lambert(torch.from_numpy(n), torch.from_numpy(points), torch.from_numpy(eyes), scene)
        image = torch.empty(v * h * w, scene.channels, dtype=torch.float64)
        image[:] = torch.as_tensor(scene.background, dtype=torch.float64)
        image[torch.from_numpy(idx)] = rgb
        mask = torch.from_numpy(hits.hit.copy())
        return TargetImages(images=image.reshape(v, h, w, -1).float(), masks=mask.reshape(v, h, w))


def boundary_edges(mesh: trimesh.Trimesh) -> int:
    """Edges used by exactly one face: the rims of the mesh's holes."""
    return int(len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)))


def close_small_holes(mesh: trimesh.Trimesh, max_hole_edges: int, name: str) -> int:
    """Closes the holes of a mesh that is not watertight (``trimesh.repair.fill_holes``, in place)
    when they have at most ``max_hole_edges`` boundary edges in all.

    Args:
        name: the mesh's file, for the messages.
    Returns:
        the boundary edges closed (0 for a watertight mesh).
    Raises:
        ValueError naming ``name``: more boundary edges than allowed, no boundary edge but still not
        watertight (non-manifold edges, which filling cannot mend), or still open after filling.
    """
    check_int(max_hole_edges, "max_hole_edges", minimum=0)
    if mesh.is_watertight:
        return 0
    advice = ("multi-view reconstruction and its error need a closed surface; repair the mesh first "
              "(e.g. trimesh.repair.fill_holes)")
    open_edges = boundary_edges(mesh)
    if open_edges == 0:
        raise ValueError(f"target mesh file {name!r} is not watertight ({len(mesh.faces)} faces, non-manifold "
                         f"edges but no hole to fill): {advice}")
    if open_edges > max_hole_edges:
        raise ValueError(f"target mesh file {name!r} is not watertight ({len(mesh.faces)} faces, {open_edges} "
                         f"boundary edges): {advice}, or let target_settings.max_hole_edges={open_edges} close "
                         f"its holes (now {max_hole_edges})")
    trimesh.repair.fill_holes(mesh)
    if not mesh.is_watertight:
        raise ValueError(f"target mesh file {name!r} is still open after filling its {open_edges} boundary edges: "
                         f"{advice}")
    return open_edges


def load_mesh(path: str | Path, max_hole_edges: int = 0) -> trimesh.Trimesh:
    """Reads a closed triangle mesh from a file and orients it outwards. With ``max_hole_edges``
    above 0, holes of at most that many boundary edges in all are closed first
    (``close_small_holes``), with a warning that says how many; the mesh's ``metadata`` records
    them as ``"holes_closed"``.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unsupported format, unreadable, empty, or not watertight beyond what
            ``max_hole_edges`` allows (each names the file).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if p.is_dir():
        raise ValueError(f"target {str(p)!r} is a folder; give a mesh file ({', '.join(MESH_FORMATS)}) or a "
                         f"built-in shape ({', '.join(SHAPES)})")
    if suffix not in MESH_FORMATS:
        raise ValueError(f"target mesh file {str(p)!r} has an unsupported format {suffix or '(none)'!r}; "
                         f"expected one of {', '.join(MESH_FORMATS)}")
    if not p.is_file():
        raise FileNotFoundError(f"target mesh file not found: {str(p)!r}")
    if p.stat().st_size == 0:
        raise ValueError(f"target mesh file {str(p)!r} is empty (0 bytes)")
    try:
        mesh = trimesh.load(str(p), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for malformed files
        # An ImportError is trimesh reaching for an optional decoder after the file failed to parse
        # (a corrupt binary STL is retried as text): its module name would mislead.
        first = str(exc).splitlines()[0] if str(exc) else ""
        detail = "" if isinstance(exc, ImportError) else f" ({type(exc).__name__}: {first})"
        raise ValueError(f"could not read target mesh file {str(p)!r}: not a valid {suffix[1:].upper()} "
                         f"file{detail}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        # What a corrupt file gives depends on trimesh's optional decoders (charset_normalizer
        # present: an empty mesh; absent: an ImportError above), so both say the same.
        raise ValueError(f"target mesh file {str(p)!r} holds no triangles: not a valid {suffix[1:].upper()} "
                         f"file, or an empty one")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"target mesh file {str(p)!r} has non-finite vertex coordinates")
    closed = close_small_holes(mesh, max_hole_edges, str(p))
    if closed:
        log.warning("target mesh file %s: closed holes with %d boundary edges (trimesh.repair.fill_holes)",
                    p, closed)
    mesh.metadata["holes_closed"] = closed
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def shape_mesh(name: str, resolution: int = 192) -> trimesh.Trimesh:
    """A fine mesh of a built-in shape (its own frame): marching cubes at ``resolution`` samples
    along the longest side of the shape's bounds, vertices then projected onto the zero set by two
    Newton steps of the implicit function."""
    if name not in SHAPES:
        raise ValueError(f"unknown shape {name!r}; built-in shapes: {', '.join(SHAPES)}")
    check_int(resolution, "resolution", minimum=16)
    shape = SHAPES[name]
    lo = np.array(shape.bounds_min, dtype=np.float64)
    hi = np.array(shape.bounds_max, dtype=np.float64)
    step = float((hi - lo).max()) / (resolution - 1)
    counts = np.maximum(np.ceil((hi - lo) / step).astype(int) + 1, 2)
    hi = lo + (counts - 1) * step
    axes = [torch.linspace(float(lo[a]), float(hi[a]), int(counts[a]), dtype=torch.float64) for a in range(3)]
    values = shape.fn(torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1))
    mesh = sdf_to_mesh(values, lo, hi)
    verts = torch.from_numpy(np.asarray(mesh.vertices, dtype=np.float64))
    for _ in range(2):
        p = verts.clone().requires_grad_(True)
        f = shape.fn(p)
        (g,) = torch.autograd.grad(f.sum(), p)
        g2 = (g * g).sum(-1, keepdim=True)
        step_v = torch.where(g2 > 1e-12, f.detach()[:, None] * g / g2.clamp(min=1e-12), torch.zeros_like(g))
        # Never move a vertex by more than one marching-cubes cell (kinks of the function).
        verts = verts - step_v.clamp(-step, step)
    return trimesh.Trimesh(vertices=verts.numpy(), faces=np.asarray(mesh.faces), process=False)


def normalise_mesh(mesh: trimesh.Trimesh, extent: float) -> tuple[trimesh.Trimesh, float]:
    """A copy of ``mesh`` centred on the origin (bounding-box centre) with its longest bbox side
    equal to ``extent``; also returns the scale factor applied."""
    check_positive(extent, "extent")
    lo, hi = mesh.bounds
    side = float((hi - lo).max())
    if not side > 0:
        raise ValueError("the target mesh has zero extent (all vertices coincide)")
    scale = extent / side
    out = mesh.copy()
    out.apply_translation(-(lo + hi) / 2.0)
    out.apply_scale(scale)
    return out, scale


def make_target(spec: str, extent: float = 1.6, normals: str = "smooth", mesh_resolution: int = 192,
                max_hole_edges: int = 0) -> Target:
    """The target named by ``spec``: a built-in shape name (see ``mvr.shapes.SHAPES``) or a mesh file.

    Args:
        spec: shape name or path to a .obj/.ply/.off/.stl/.glb file.
        extent: longest side of the normalised target's bounding box (world units; the grid's box
            must hold it).
        normals: "smooth" or "face" (see the module docstring).
        mesh_resolution: marching-cubes samples along the longest side for built-in shapes.
        max_hole_edges: a mesh file's holes of at most this many boundary edges in all are closed
            (``close_small_holes``; 0: a mesh that is not watertight is refused).
    """
    if not isinstance(spec, (str, Path)) or not str(spec):
        raise TypeError(f"target must be a shape name or a mesh file path, got {spec!r}")
    spec = str(spec)
    if spec in SHAPES:
        raw = shape_mesh(spec, mesh_resolution)
        mesh, scale = normalise_mesh(raw, extent)
        return Target(spec, f"builtin:{spec}", mesh, scale, normals)
    if Path(spec).suffix == "" and not Path(spec).exists():
        raise ValueError(f"target {spec!r} is neither a built-in shape ({', '.join(SHAPES)}) nor a mesh "
                         f"file ({', '.join(MESH_FORMATS)})")
    loaded = load_mesh(spec, max_hole_edges)
    mesh, scale = normalise_mesh(loaded, extent)
    return Target(Path(spec).stem, str(spec), mesh, scale, normals, loaded.metadata["holes_closed"])
