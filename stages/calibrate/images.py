"""Finding and checking the input photos before any SfM work starts."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rfir_core.errors import InputFileError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


@dataclass
class ImageSet:
    """The photos of one calibration: folder, sorted file names (relative), and their common size."""

    folder: Path
    names: list[str]
    width: int
    height: int

    def path(self, name: str) -> Path:
        return self.folder / name


def _read_size(path: Path) -> tuple[int, int] | None:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        return None
    return int(image.shape[1]), int(image.shape[0])


def scan_images(folder: str | Path, min_images: int = 3) -> ImageSet:
    """List the photos in `folder` (not recursive) and check they are readable and the same size.

    Raises InputFileError for a missing or empty folder, fewer than `min_images` photos,
    unreadable files, or mixed image sizes (one camera is assumed).
    """
    folder = Path(folder)
    if not folder.exists():
        raise InputFileError("image folder not found", path=folder)
    if not folder.is_dir():
        raise InputFileError("expected a folder of images", path=folder)
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise InputFileError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in the folder", path=folder)
    if len(names) < min_images:
        raise InputFileError(f"only {len(names)} image(s); structure from motion needs at least {min_images} "
                             "overlapping photos", path=folder)
    sizes: dict[tuple[int, int], list[str]] = {}
    unreadable = []
    for name in names:
        size = _read_size(folder / name)
        if size is None:
            unreadable.append(name)
        else:
            sizes.setdefault(size, []).append(name)
    if unreadable:
        shown = ", ".join(unreadable[:5]) + (" ..." if len(unreadable) > 5 else "")
        raise InputFileError(f"{len(unreadable)} image(s) cannot be read (damaged or not images): {shown}", path=folder)
    if len(sizes) > 1:
        ordered = sorted(sizes.items(), key=lambda kv: -len(kv[1]))
        (w, h), _ = ordered[0]
        odd = [f"{n} ({s[0]}x{s[1]})" for s, ns in ordered[1:] for n in ns]
        raise InputFileError(f"images have mixed sizes: most are {w}x{h} but {', '.join(odd[:5])}"
                             f"{' ...' if len(odd) > 5 else ''}; calibrate assumes one camera, so resize or "
                             "split the photos", path=folder)
    (width, height), = sizes
    return ImageSet(folder, names, width, height)
