"""Camera geometry between the drone and the simulator: a real frame mapped into the view the policy trained on.

The simulator renders a square image of ``env.image_size`` pixels with a pinhole camera whose field of view is
``env.fov_deg`` across (PyBullet's ``computeProjectionMatrixFOV`` with aspect 1: the same angle vertically and
horizontally). The DJI Tello's 82.6° is its **diagonal** field of view; for its 960 × 720 (4:3) video that is a
pinhole with f = 600 / tan(41.3°) ≈ 683 px, about 70.2° × 55.6°. Squashing the 4:3 frame into the square (what a
plain resize does) distorts every angle. :class:`CameraView` instead resamples the real frame through both
cameras' intrinsics, so a point in the world lands on the same pixel of the policy's input as in simulation;
the parts of the simulated view that the real camera does not see (with the defaults, the outer bands: the
Tello covers the central 80 % × 60 % of an 82.6° square) are filled by replicating the nearest edge pixel.
``docs/deploy.md`` (Camera geometry) says what that means for a policy and how to train one whose view the Tello
covers whole (``env.fov_deg=55.6``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole camera: image ``width`` × ``height`` px, focal lengths ``fx``, ``fy`` and principal point
    ``cx``, ``cy`` in px (pixel centres at integer + 0.5: the image spans [0, width] × [0, height])."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_diagonal_fov(cls, width: int, height: int, fov_deg: float) -> CameraIntrinsics:
        """Square pixels, centred principal point, ``fov_deg`` across the image diagonal."""
        f = math.hypot(width, height) / 2.0 / math.tan(math.radians(fov_deg) / 2.0)
        return cls(int(width), int(height), f, f, width / 2.0, height / 2.0)

    @classmethod
    def square(cls, size: int, fov_deg: float) -> CameraIntrinsics:
        """The simulator's camera: ``size`` × ``size`` px, ``fov_deg`` across (and up)."""
        f = size / 2.0 / math.tan(math.radians(fov_deg) / 2.0)
        return cls(int(size), int(size), f, f, size / 2.0, size / 2.0)

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same camera at another resolution (a decoder's or driver's resize keeps the field of view)."""
        kx, ky = width / self.width, height / self.height
        return CameraIntrinsics(int(width), int(height), self.fx * kx, self.fy * ky, self.cx * kx, self.cy * ky)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) (u right, v down) of points (N, 3) in the camera frame (x forward, y left,
        z up, m; x > 0)."""
        p = np.asarray(points, np.float64)
        return np.stack([self.cx - self.fx * p[:, 1] / p[:, 0], self.cy - self.fy * p[:, 2] / p[:, 0]], 1)

    def fov_deg(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view in degrees."""
        return (
            math.degrees(2 * math.atan(self.width / 2.0 / self.fx)),
            math.degrees(2 * math.atan(self.height / 2.0 / self.fy)),
        )


# The Tello's video stream as djitellopy decodes it: 960 × 720, 82.6° diagonal (DJI's specification).
TELLO = CameraIntrinsics.from_diagonal_fov(960, 720, 82.6)


class CameraView:
    """Resample frames of camera ``source`` into the simulator's square view (``fov_deg``, ``size`` px).

    ``coverage`` is the share of the simulated view's pixels that the source camera sees (the rest replicate
    the nearest edge pixel).
    """

    def __init__(self, source: CameraIntrinsics, fov_deg: float, size: int) -> None:
        self.source, self.target = source, CameraIntrinsics.square(size, fov_deg)
        t, s = self.target, source
        u, v = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
        # The ray through each target pixel, then where it meets the source image (both pinholes, same centre).
        x_over = (u - t.cx) / t.fx
        y_over = (v - t.cy) / t.fy
        self.map_x = (s.cx + s.fx * x_over - 0.5).astype(np.float32)
        self.map_y = (s.cy + s.fy * y_over - 0.5).astype(np.float32)
        inside = (
            (self.map_x >= -0.5) & (self.map_x <= s.width - 0.5) & (self.map_y >= -0.5) & (self.map_y <= s.height - 0.5)
        )
        self.coverage = float(inside.mean())

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 frame of the source camera → (size, size, 3) uint8 in the simulator's geometry."""
        import cv2

        h, w = frame.shape[:2]
        if (w, h) != (self.source.width, self.source.height):
            raise ValueError(
                f"camera frame is {w}×{h} px, the camera's intrinsics are for {self.source.width}×{self.source.height}"
            )
        return cv2.remap(
            np.ascontiguousarray(frame),
            self.map_x,
            self.map_y,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
