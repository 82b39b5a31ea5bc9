"""Provenance: how an artifact was made (config, inputs, code revision, versions, device, time)."""
from __future__ import annotations

import hashlib
import json
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__
from .output_guard import note_input


def sha256_file(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk_bytes):
            digest.update(block)
    return digest.hexdigest()


def git_revision() -> str:
    """The rfir checkout's commit (with '+dirty' for local changes), or 'unknown'."""
    root = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def library_versions() -> dict[str, str]:
    """Versions of the libraries that shape results (only those already imported or cheap)."""
    versions = {"rfir": __version__, "python": platform.python_version()}
    for name in ("numpy", "torch", "h5py", "sionna.rt", "mitsuba", "pycolmap", "open3d"):
        module = sys.modules.get(name)
        if module is not None and hasattr(module, "__version__"):
            versions[name] = str(module.__version__)
    return versions


@dataclass
class Provenance:
    """What goes into an artifact's /provenance group.

    config_toml: the resolved configuration as TOML text.
    inputs: input file path -> SHA-256.
    extra: free-form JSON-serialisable details (edit history, split seed, timings per phase).
    """

    stage: str
    config_toml: str = ""
    inputs: dict[str, str] = field(default_factory=dict)
    device: str = "cpu"
    command: str = field(default_factory=lambda: " ".join(sys.argv))
    git_revision: str = field(default_factory=git_revision)
    versions: dict[str, str] = field(default_factory=library_versions)
    started: float = field(default_factory=time.time)
    wall_time_s: float | None = None
    extra: dict = field(default_factory=dict)

    def add_input(self, path: str | Path) -> None:
        """Record an input file by its hash (and, while a command runs, as a file no output may replace)."""
        note_input(path)
        self.inputs[str(path)] = sha256_file(path)

    def to_attrs(self) -> dict[str, str | float]:
        """Flatten to HDF5 attributes (strings and floats only)."""
        wall = self.wall_time_s if self.wall_time_s is not None else time.time() - self.started
        return {
            "stage": self.stage,
            "config_toml": self.config_toml,
            "inputs_json": json.dumps(self.inputs, sort_keys=True),
            "device": self.device,
            "command": self.command,
            "git_revision": self.git_revision,
            "versions_json": json.dumps(self.versions, sort_keys=True),
            "wall_time_s": float(wall),
            "extra_json": json.dumps(self.extra, sort_keys=True, default=str),
        }

    @classmethod
    def from_attrs(cls, attrs: dict) -> "Provenance":
        """Inverse of to_attrs (tolerates missing keys from hand-written files)."""
        return cls(
            stage=str(attrs.get("stage", "")),
            config_toml=str(attrs.get("config_toml", "")),
            inputs=json.loads(attrs.get("inputs_json", "{}")),
            device=str(attrs.get("device", "")),
            command=str(attrs.get("command", "")),
            git_revision=str(attrs.get("git_revision", "")),
            versions=json.loads(attrs.get("versions_json", "{}")),
            wall_time_s=float(attrs["wall_time_s"]) if "wall_time_s" in attrs else None,
            extra=json.loads(attrs.get("extra_json", "{}")),
        )
