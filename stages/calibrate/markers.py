"""ArUco markers of known size and placement as metric references (detected with OpenCV).

Layout file (CSV): `id,size_m,x,y,z,yaw_deg` per marker: the marker's centre in the world (m),
its side length (black border included) and its rotation about +z. Markers lie flat, facing up
(+z); at yaw 0 the top edge of the printed marker points to +y and its right edge to +x. Each
detected corner becomes a known 3D point observed in that image.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError

from .align import PointReferences
from .images import ImageSet


def marker_corners(size_m: float, centre, yaw_deg: float) -> np.ndarray:
    """World corners (4,3) in OpenCV's ArUco order: top-left, top-right, bottom-right, bottom-left."""
    h = 0.5 * size_m
    local = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    xy = local @ np.array([[c, s], [-s, c]])
    return np.column_stack([xy, np.zeros(4)]) + np.asarray(centre, float)


def load_layout(path: str | Path) -> dict[int, np.ndarray]:
    """Marker id -> world corners (4,3) from a layout CSV."""
    path = Path(path)
    if not path.exists():
        raise InputFileError("marker layout file not found", path=path)
    layout = {}
    with open(path, newline="") as handle:
        for lineno, row in enumerate(csv.reader(handle), start=1):
            row = [c.strip() for c in row]
            if not row or not any(row) or row[0].startswith("#"):
                continue
            if len(row) < 6:
                raise InputFileError(f"line {lineno}: expected id,size_m,x,y,z,yaw_deg", path=path)
            try:
                mid, size = int(row[0]), float(row[1])
                centre, yaw = [float(c) for c in row[2:5]], float(row[5])
            except ValueError:
                if lineno == 1:
                    continue
                raise InputFileError(f"line {lineno}: id must be an integer, the rest numbers", path=path) from None
            if size <= 0:
                raise InputFileError(f"line {lineno}: marker size must be positive (metres)", path=path)
            layout[mid] = marker_corners(size, centre, yaw)
    if not layout:
        raise InputFileError("no markers (expected lines of id,size_m,x,y,z,yaw_deg)", path=path)
    return layout


def _detector(dictionary: str):
    import cv2

    name = dictionary.upper()
    if not hasattr(cv2.aruco, name):
        raise ConfigError(f"unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50, DICT_6X6_250)")
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)), params)


def detect(images: ImageSet, dictionary: str = "DICT_4X4_50") -> dict[int, list[tuple[str, np.ndarray]]]:
    """Marker id -> [(image name, corners (4,2) px)] over all photos."""
    import cv2

    detector = _detector(dictionary)
    found: dict[int, list] = {}
    for name in images.names:
        gray = cv2.imread(str(images.path(name)), cv2.IMREAD_GRAYSCALE)
        corners, ids, _ = detector.detectMarkers(gray)
        for c, i in zip(corners, [] if ids is None else ids.ravel()):
            found.setdefault(int(i), []).append((name, np.asarray(c, float).reshape(4, 2)))
    return found


def marker_references(images: ImageSet, layout_path: str | Path, dictionary: str = "DICT_4X4_50") -> PointReferences:
    """Known 3D points (marker corners) with their detections, for align_to_points."""
    layout = load_layout(layout_path)
    found = detect(images, dictionary)
    labels, xyz, obs = [], [], []
    for mid, corners_w in sorted(layout.items()):
        for k in range(4):
            seen = [(name, float(c[k, 0]), float(c[k, 1])) for name, c in found.get(mid, [])]
            if seen:
                labels.append(f"marker{mid}.{k}")
                xyz.append(corners_w[k])
                obs.append(seen)
    if not labels:
        raise InputFileError(f"none of the {len(layout)} markers in the layout was detected in the photos "
                             f"(dictionary {dictionary}; detected ids: {sorted(found) or 'none'})", path=layout_path)
    return PointReferences(labels, np.asarray(xyz), obs, str(layout_path))
