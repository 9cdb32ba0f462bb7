"""Batched pinhole cameras (``Cameras``) and the coordinate conventions of the whole project, which
this is the one place to document. The world is right-handed with y up, and the benchmarks' objects
live around the origin. A camera is an eye position and three orthonormal world vectors:
``forward`` (the viewing direction), ``right`` (the image's +column direction) and ``up`` (the
image's -row direction). Images are (H, W), row 0 at the top and column 0 on the left, and rays go
through pixel centres: pixel (r, c) looks along
``forward + sx * tan(fov/2) * aspect * right + sy * tan(fov/2) * up`` with
``sx = 2 (c + 0.5) / W - 1``, ``sy = 1 - 2 (r + 0.5) / H`` and ``aspect = W / H``, where ``fov``
is the full vertical field of view. ``Cameras.look_at`` builds right-handed cameras and
``Cameras.nmr`` the NMR ShapeNet benchmark's left-handed ones, the mirror image; their docstrings
give the axes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Union

import torch

SizeLike = Union[int, Sequence[int]]

NMR_ELEVATION_DEG = 30.0
NMR_DISTANCE = 2.732
NMR_FOV_DEG = 30.0
NMR_NUM_VIEWS = 24  # the NMR ShapeNet dataset's views per object (azimuth steps of 15 degrees)


def _image_size(image_size: SizeLike) -> tuple[int, int]:
    if isinstance(image_size, bool):
        raise ValueError(f"image_size must be a positive int or (H, W), got {image_size!r}")
    if isinstance(image_size, int):
        hw = (image_size, image_size)
    else:
        try:
            hw = tuple(int(s) for s in image_size)
        except TypeError:
            raise ValueError(f"image_size must be a positive int or (H, W), got {image_size!r}") from None
    if len(hw) != 2 or min(hw) <= 0:
        raise ValueError(f"image_size must be a positive int or (H, W) of positive ints, got {image_size!r}")
    return hw  # type: ignore[return-value]


def _vec3(x, name: str, dtype: torch.dtype, device) -> torch.Tensor:
    t = torch.as_tensor(x, dtype=dtype, device=device)
    if t.ndim == 1:
        t = t.unsqueeze(0)
    if t.ndim != 2 or t.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (3,) or (B, 3), got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite")
    return t


def rotation_matrices(rotation: torch.Tensor) -> torch.Tensor:
    """(B, 3) rotation vectors (the direction the axis, the length the angle in radians) -> (B, 3, 3)
    rotation matrices, by the exponential of their cross-product matrices (exact, and
    differentiable at 0)."""
    r = rotation
    zero = torch.zeros_like(r[:, 0])
    skew = torch.stack([torch.stack([zero, -r[:, 2], r[:, 1]], -1),
                        torch.stack([r[:, 2], zero, -r[:, 0]], -1),
                        torch.stack([-r[:, 1], r[:, 0], zero], -1)], -2)
    return torch.linalg.matrix_exp(skew)


def _normalize(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True)


@dataclass(frozen=True)
class Cameras:
    """A batch of B pinhole cameras sharing one image size.

    Attributes:
        eye: (B, 3) world positions.
        forward, right, up: (B, 3) orthonormal world directions (see the module docstring).
        fov_deg: (B,) full vertical field of view in degrees.
        image_size: (H, W).
    """

    eye: torch.Tensor
    forward: torch.Tensor
    right: torch.Tensor
    up: torch.Tensor
    fov_deg: torch.Tensor
    image_size: tuple[int, int]

    # ------------------------------------------------------------------ constructors
    @classmethod
    def look_at(
        cls,
        eye,
        at=(0.0, 0.0, 0.0),
        up=(0.0, 1.0, 0.0),
        fov_deg: Union[float, Sequence[float], torch.Tensor] = 60.0,
        image_size: SizeLike = 64,
        dtype: torch.dtype = torch.float32,
        device: Union[str, torch.device] = "cpu",
    ) -> "Cameras":
        """Right-handed look-at cameras: ``right = forward x up``, so a camera on +z looking at the
        origin sees world +x to the right of the image.

        Args:
            eye: (3,) or (B, 3) camera positions (world).
            at: (3,) or (B, 3) points looked at.
            up: (3,) or (B, 3) approximate up directions (not parallel to ``at - eye``).
            fov_deg: full vertical field of view, scalar or (B,), in (0, 180).
            image_size: int or (H, W).
        """
        return cls._build(eye, at, up, fov_deg, image_size, dtype, device, left_handed=False)

    @classmethod
    def nmr(
        cls,
        views: Union[int, Sequence[int], torch.Tensor],
        image_size: SizeLike = 64,
        dtype: torch.dtype = torch.float32,
        device: Union[str, torch.device] = "cpu",
        distance: float = NMR_DISTANCE,
        elevation_deg: Union[float, Sequence[float], torch.Tensor] = NMR_ELEVATION_DEG,
    ) -> "Cameras":
        """The NMR ShapeNet benchmark cameras for view indices (B,) (0..23 for the dataset's views).

        They reproduce the NMR ShapeNet renders (Kato et al.): the eye at elevation e
        (``elevation_deg``, 30 degrees), distance d (``distance``, 2.732) and azimuth a = ``-15 k``
        degrees for view k, ``eye = (d cos e sin a, d sin e, -d cos e cos a)``, a full field of view
        of 30 degrees, and the benchmark's left-handed axes ``z_c = normalize(at - eye)``,
        ``x_c = normalize(up x z_c)``, ``y_c = z_c x x_c`` (``at`` the origin, ``up`` +y): here
        ``right = x_c`` (the mirror image of ``look_at``) and ``up = y_c``. Fractional view indices
        are allowed (azimuth ``-15 * view`` degrees), and so is one elevation per view (a (B,)
        ``elevation_deg``, each in (-90, 90)): views the dataset does not hold.
        """
        v = torch.as_tensor(views, dtype=torch.float64).reshape(-1)
        if v.numel() == 0:
            raise ValueError("views must hold at least one view index")
        if not bool(torch.isfinite(v).all()):
            raise ValueError("views must be finite")
        el = torch.as_tensor(elevation_deg, dtype=torch.float64).reshape(-1)
        if el.numel() not in (1, v.numel()):
            raise ValueError(f"elevation_deg must be one number or one per view ({v.numel()}), got {el.numel()}")
        if not bool(((el > -90.0) & (el < 90.0)).all()):
            raise ValueError(f"elevation_deg must lie in (-90, 90) degrees, got {el.tolist()[:4]}")
        az = torch.deg2rad(-15.0 * v)
        el = torch.deg2rad(el).expand_as(az)
        eye = torch.stack([
            distance * torch.cos(el) * torch.sin(az),
            distance * torch.sin(el),
            -distance * torch.cos(el) * torch.cos(az),
        ], dim=-1)
        return cls._build(eye, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), NMR_FOV_DEG, image_size, dtype, device,
                          left_handed=True)

    @classmethod
    def cube_rig(
        cls,
        distance: float,
        at=(0.0, 0.0, 0.0),
        fov_deg: float = 60.0,
        image_size: SizeLike = 64,
        dtype: torch.dtype = torch.float32,
        device: Union[str, torch.device] = "cpu",
    ) -> "Cameras":
        """The 26 views of paper section 5: eyes on the 6 face centres, 12 edge midpoints and 8
        corners of a cube around ``at``, each at ``distance`` from it, looking at it.

        Order: faces, then edges, then corners. Up is +y, or +z for the two views on the y axis.
        """
        if not distance > 0:
            raise ValueError(f"distance must be positive, got {distance}")
        dirs = []
        for n_nonzero in (1, 2, 3):
            for i in (-1, 0, 1):
                for j in (-1, 0, 1):
                    for k in (-1, 0, 1):
                        if (i != 0) + (j != 0) + (k != 0) == n_nonzero:
                            dirs.append((i, j, k))
        d = torch.tensor(dirs, dtype=torch.float64)
        d = d / d.norm(dim=-1, keepdim=True)
        at_t = torch.as_tensor(at, dtype=torch.float64).reshape(1, 3)
        eye = at_t + distance * d
        up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(len(dirs), 3).clone()
        on_y = (d[:, 0].abs() < 1e-9) & (d[:, 2].abs() < 1e-9)
        up[on_y] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        return cls._build(eye, at_t, up, fov_deg, image_size, dtype, device, left_handed=False)

    @classmethod
    def _build(cls, eye, at, up, fov_deg, image_size, dtype, device, left_handed: bool) -> "Cameras":
        hw = _image_size(image_size)
        eye_t = _vec3(eye, "eye", torch.float64, device)
        at_t = _vec3(at, "at", torch.float64, device)
        up_t = _vec3(up, "up", torch.float64, device)
        b = max(eye_t.shape[0], at_t.shape[0], up_t.shape[0])
        for name, t in (("eye", eye_t), ("at", at_t), ("up", up_t)):
            if t.shape[0] not in (1, b):
                raise ValueError(f"{name} has batch {t.shape[0]}, expected 1 or {b}")
        eye_t, at_t, up_t = eye_t.expand(b, 3), at_t.expand(b, 3), up_t.expand(b, 3)
        fov = torch.as_tensor(fov_deg, dtype=torch.float64, device=device).reshape(-1)
        if fov.shape[0] not in (1, b):
            raise ValueError(f"fov_deg has {fov.shape[0]} entries, expected 1 or {b}")
        if not bool(((fov > 0) & (fov < 180)).all()):
            raise ValueError(f"fov_deg must lie in (0, 180) degrees, got {fov.tolist()}")
        fov = fov.expand(b)
        view = at_t - eye_t
        dist = view.norm(dim=-1)
        if bool((dist <= 1e-12).any()):
            raise ValueError("eye and at must differ (zero viewing direction)")
        up_len = up_t.norm(dim=-1)
        if bool((up_len <= 1e-12).any()):
            raise ValueError("up must be a non-zero vector")
        forward = view / dist[:, None]
        up_n = up_t / up_len[:, None]
        if left_handed:
            side = torch.cross(up_n, forward, dim=-1)
        else:
            side = torch.cross(forward, up_n, dim=-1)
        side_len = side.norm(dim=-1)
        if bool((side_len <= 1e-9).any()):
            raise ValueError("up must not be parallel to the viewing direction (at - eye)")
        right = side / side_len[:, None]
        if left_handed:
            true_up = torch.cross(forward, right, dim=-1)
        else:
            true_up = torch.cross(right, forward, dim=-1)
        cast = lambda t: t.to(dtype=dtype).contiguous()  # noqa: E731
        return cls(cast(eye_t), cast(forward), cast(right), cast(true_up), cast(fov), hw)

    # ------------------------------------------------------------------ use
    @property
    def batch_size(self) -> int:
        return self.eye.shape[0]

    @property
    def dtype(self) -> torch.dtype:
        return self.eye.dtype

    @property
    def device(self) -> torch.device:
        return self.eye.device

    @property
    def requires_grad(self) -> bool:
        """Whether any of the cameras' tensors carries a gradient (a pose being optimised, as
        ``moved`` gives): the render is then differentiable w.r.t. the cameras too."""
        return any(t.requires_grad for t in (self.eye, self.forward, self.right, self.up, self.fov_deg))

    def detach(self) -> "Cameras":
        """The same cameras without gradients."""
        return Cameras(self.eye.detach(), self.forward.detach(), self.right.detach(), self.up.detach(),
                       self.fov_deg.detach(), self.image_size)

    def moved(self, rotation=None, translation=None) -> "Cameras":
        """The cameras turned about their eyes and shifted, differentiably (for optimising poses).

        Args:
            rotation: (3,) or (B, 3) rotation vectors in world axes (radians; the direction is the
                axis, the length the angle), applied to ``forward``, ``right`` and ``up``; None: none.
            translation: (3,) or (B, 3) world offsets added to ``eye``; None: none.
        Returns:
            Cameras whose tensors carry the gradients of ``rotation`` and ``translation``.
        """
        eye, forward, right, up = self.eye, self.forward, self.right, self.up
        b = self.batch_size
        if rotation is not None:
            r = torch.as_tensor(rotation, dtype=self.dtype, device=self.device)
            r = r.expand(b, 3) if r.shape == (3,) else r
            if r.shape != (b, 3):
                raise ValueError(f"rotation must have shape (3,) or ({b}, 3), got {tuple(r.shape)}")
            rot = rotation_matrices(r)  # (B, 3, 3)
            forward, right, up = ((rot @ v[..., None])[..., 0] for v in (forward, right, up))
        if translation is not None:
            t = torch.as_tensor(translation, dtype=self.dtype, device=self.device)
            t = t.expand(b, 3) if t.shape == (3,) else t
            if t.shape != (b, 3):
                raise ValueError(f"translation must have shape (3,) or ({b}, 3), got {tuple(t.shape)}")
            eye = eye + t
        return Cameras(eye, forward, right, up, self.fov_deg, self.image_size)

    def to(self, device=None, dtype: torch.dtype | None = None) -> "Cameras":
        """The same cameras on another device and/or dtype."""
        f = lambda t: t.to(device=device, dtype=dtype or t.dtype)  # noqa: E731
        return Cameras(f(self.eye), f(self.forward), f(self.right), f(self.up), f(self.fov_deg), self.image_size)

    def __getitem__(self, index) -> "Cameras":
        """A sub-batch: ``cams[2:5]``, ``cams[[0, 3]]`` or ``cams[mask]``."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        return Cameras(self.eye[index], self.forward[index], self.right[index], self.up[index],
                       self.fov_deg[index], self.image_size)

    @property
    def pixel_angle(self) -> torch.Tensor:
        """(B,) angular size of one pixel at the image centre (radians, small-angle): a pixel covers
        ``t * pixel_angle`` world units at distance t."""
        h = self.image_size[0]
        return 2.0 * torch.tan(torch.deg2rad(self.fov_deg) / 2.0) / h

    def rays(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Rays through the pixel centres.

        Returns:
            origins: (B, H, W, 3) world (an expanded view of ``eye``, no copy).
            directions: (B, H, W, 3) unit world directions.
        """
        h, w = self.image_size
        dt, dev = self.dtype, self.device
        tan_half = torch.tan(torch.deg2rad(self.fov_deg) / 2.0)  # (B,)
        sx = (2.0 * (torch.arange(w, dtype=dt, device=dev) + 0.5) / w - 1.0) * (w / h)
        sy = 1.0 - 2.0 * (torch.arange(h, dtype=dt, device=dev) + 0.5) / h
        sx = sx[None, None, :, None] * tan_half[:, None, None, None]
        sy = sy[None, :, None, None] * tan_half[:, None, None, None]
        d = (self.forward[:, None, None, :] + sx * self.right[:, None, None, :]
             + sy * self.up[:, None, None, :])
        d = _normalize(d)
        o = self.eye[:, None, None, :].expand(-1, h, w, 3)
        return o, d

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Projects world points to continuous pixel coordinates.

        Args:
            points: (B, P, 3) or (P, 3) world points (the latter shared by all cameras).
        Returns:
            pixels: (B, P, 2) continuous (column, row) in pixels, integral at pixel centres: the
                centre of pixel (r, c) (the point its ``rays`` direction goes through) projects to
                exactly (c, r), and the image's top-left corner to (-0.5, -0.5).
            depth: (B, P) the point's coordinate along ``forward`` (z in the camera frame, not the
                distance to the eye; positive in front of the camera).
        """
        if points.ndim == 2:
            points = points.unsqueeze(0).expand(self.batch_size, -1, -1)
        h, w = self.image_size
        rel = points.to(self.dtype) - self.eye[:, None, :]
        z = (rel * self.forward[:, None, :]).sum(-1)
        x = (rel * self.right[:, None, :]).sum(-1)
        y = (rel * self.up[:, None, :]).sum(-1)
        tan_half = torch.tan(torch.deg2rad(self.fov_deg) / 2.0)[:, None]
        sx = x / z / (tan_half * (w / h))
        sy = y / z / tan_half
        col = (sx + 1.0) * w / 2.0 - 0.5
        row = (1.0 - sy) * h / 2.0 - 0.5
        return torch.stack([col, row], dim=-1), z
