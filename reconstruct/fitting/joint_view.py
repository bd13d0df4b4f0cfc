"""The cameras' views for the joint end model (joint revision 19): whether the scan could have seen a log's
top at a place along its axis.

A bin along a log's axis reads "below" (:data:`reconstruct.fitting.joint_ends.BELOW`) where the scan has
points under where the log's top would be, "over" where it has points over it; past the log's end the ground
or a lower log, or a log across. Either is evidence of where the log ends only where the scan would have seen
the log's top, had the log been there: where that top lies inside both images of a stereo pair. A raised log
running out of the pairs' views shows the cameras the ground under it before its top leaves the images (the
top is nearer the cameras than the ground, so the image edge cuts it off first): those bins read "below"
inside the log. :func:`in_view` is that test; :func:`scan_views` reads the pairs' cameras from the scan.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class PairView:
    """One stereo pair's two cameras: the left camera's pose in the frame in use (4x4, that frame <- camera),
    the intrinsics (3x3 [px]), the right camera from the left (``x_right = R x_left + T`` [m]) and the image
    size (width, height) [px]."""

    T_frame_cam: np.ndarray
    K_left: np.ndarray
    K_right: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]

    def moved(self, T_new_frame: np.ndarray) -> "PairView":
        """The same cameras in another frame (``T_new_frame``: new <- current)."""
        return PairView(np.asarray(T_new_frame, dtype=float) @ self.T_frame_cam, self.K_left, self.K_right, self.R,
                        self.T, self.image_size)

    def sees(self, points: np.ndarray, margin_px: float) -> np.ndarray:
        """Per point ((N, 3), the frame in use), whether it lies in front of both cameras and inside both
        images, ``margin_px`` in from their edges (lens distortion ignored: the twin's and a ZED's are small)."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        T_cam = np.linalg.inv(self.T_frame_cam)
        left = P @ T_cam[:3, :3].T + T_cam[:3, 3]
        right = left @ self.R.T + self.T
        w, h = self.image_size
        ok = np.ones(len(P), bool)
        for X, K in ((left, self.K_left), (right, self.K_right)):
            z = X[:, 2]
            uv = (X[:, :2] / np.where(z > 0, z, 1.0)[:, None]) @ K[:2, :2].T + K[:2, 2]
            ok &= (z > 0) & (uv[:, 0] >= margin_px) & (uv[:, 0] < w - margin_px) & (uv[:, 1] >= margin_px) \
                & (uv[:, 1] < h - margin_px)
        return ok


def in_view(views: list[PairView], points: np.ndarray, margin_px: float) -> np.ndarray:
    """Per point, whether some pair of ``views`` has it inside both its images (:meth:`PairView.sees`)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    for v in views:
        out |= v.sees(P, margin_px)
    return out


def scan_views(scan_dir: str | Path, T_frame_scan: np.ndarray) -> list[PairView] | None:
    """The pairs' cameras of the scan in ``scan_dir`` in the frame ``T_frame_scan`` maps the scan frame to, from
    each pair's ``calibration.yaml`` and its pose (``T_pile_cam``: the camera in the scan frame). None when a
    pair has no such file or pose (its view is not known: no bin is then judged by the views)."""
    from reconstruct.scan.calibration import yaml_has_pose
    from reconstruct.scan.stereo import find_pairs
    from synth.geometry.calibration import read_calibration_yaml

    views = []
    for folder in find_pairs(scan_dir):
        path = Path(folder) / "calibration.yaml"
        if not path.exists() or not yaml_has_pose(path):
            return None
        c = read_calibration_yaml(path)
        views.append(PairView(np.asarray(c.T_pile_cam, dtype=float), c.K_left, c.K_right, c.R, c.T,
                              c.image_size).moved(T_frame_scan))
    return views
