"""What a photogrammetric block looks like: its images and cameras, typed.

:class:`BlockGeometry` is made by the model builders (:func:`baarda.model.bundle.block_geometry`:
projection centres, attitudes and ground footprints at the mean terrain height;
:func:`baarda.model.sfm.sfm_geometry`: projection centres and file names) and carried by
:attr:`baarda.model.problem.Problem.geometry` (None for a geodetic network). The statistics read
the scale of the block from it — the image base of R84 §6 (:mod:`baarda.stats.robust`), the
principal distance of the radial variance model F80 §2.1 (:mod:`baarda.stats.variance`), the
images of a camera for an AP group F80 §7.2 (:mod:`baarda.stats.hypotheses`) — and the
dashboard draws it through :meth:`BlockGeometry.as_dict` (JSON-able, the same dictionary for
every consumer).

Units: object coordinates and heights in metres, angles in radians, camera quantities in the
camera's ``unit`` ("mm" for metric cameras, "px" for structure from motion).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType


@dataclass(frozen=True, eq=False)
class ImageGeometry:
    """One image: id, camera id, projection centre (X0, Y0, Z0) [m], strip ("" where the file
    has none); ``details`` holds the rest as the builder wrote it (attitude, footprint, name)."""

    id: str
    camera: str
    X0: float
    Y0: float
    Z0: float
    strip: str = ""
    details: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, eq=False)
class CameraGeometry:
    """One camera: id, unit, image width and height (camera unit), principal distance ``c`` and
    principal point (x0, y0) where the model has them (metric cameras; None for SfM models,
    whose focal lengths are parameters), the AP reference length ``ap_scale``; ``details``:
    every value as the builder wrote it."""

    id: str
    unit: str
    width: float
    height: float
    c: float | None = None
    x0: float = 0.0
    y0: float = 0.0
    ap_scale: float | None = None
    details: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, eq=False)
class BlockGeometry:
    """A block's images and cameras (module docstring). ``flying_height`` and
    ``terrain_height`` [m] are known for aerial blocks (None otherwise); ``convention`` is the
    SfM file convention (None for native blocks)."""

    images: tuple[ImageGeometry, ...]
    cameras: tuple[CameraGeometry, ...]
    image_unit: str
    image_size: tuple[float, float] | None = None
    flying_height: float | None = None
    terrain_height: float | None = None
    convention: str | None = None

    @property
    def camera(self) -> CameraGeometry | None:
        """The first camera (the block's camera when it has one)."""
        return self.cameras[0] if self.cameras else None

    def camera_by_id(self, camera_id: str) -> CameraGeometry:
        """The camera ``camera_id`` (KeyError if the block has none of that id)."""
        return self._cameras[camera_id]

    def camera_of(self, image_id: str) -> CameraGeometry:
        """The camera of image ``image_id``."""
        return self._cameras[self._image_camera[image_id]]

    def images_of(self, camera_id: str) -> set[str]:
        """Ids of the images taken with camera ``camera_id``."""
        return {im.id for im in self.images if im.camera == camera_id}

    @cached_property
    def _cameras(self) -> dict:
        return {c.id: c for c in self.cameras}

    @cached_property
    def _image_camera(self) -> dict:
        return {im.id: im.camera for im in self.images}

    @cached_property
    def _dict(self) -> dict:
        images = [{"id": im.id, **({"strip": im.strip} if "strip" in im.details else {}), "camera": im.camera,
                   "X0": im.X0, "Y0": im.Y0, "Z0": im.Z0,
                   **{k: v for k, v in im.details.items() if k != "strip"}} for im in self.images]
        cams = [dict(c.details) for c in self.cameras]
        if self.convention is not None:        # structure from motion
            out = {"images": images, "cameras": cams, "image_unit": self.image_unit, "convention": self.convention}
            if self.image_size is not None:
                out["image_size"] = list(self.image_size)
            return out
        return {"images": images, "camera": cams[0] if cams else {}, "cameras": cams,
                "image_size": list(self.image_size) if self.image_size is not None else [0, 0],
                "image_unit": self.image_unit, "flying_height": self.flying_height,
                "terrain_height": self.terrain_height}

    def as_dict(self) -> dict:
        """The geometry as a JSON-able dictionary (what the dashboard draws); one object per
        geometry — treat it as read-only."""
        return self._dict
