"""Read a triangle mesh in PLY, OBJ, STL or glTF/GLB into a mesh_io.Mesh, with labels where the format names parts.

- PLY: mesh_io.read_ply_mesh (a per-face `label`, names from a `labels.json` beside the file).
- OBJ: every `o` or `g` statement starts a part; each distinct name becomes a label of that name (faces before
  the first one: "unnamed"); a file without `o`/`g` is unlabelled. Polygons are split into triangle fans.
- STL (ASCII or binary): unlabelled; an ASCII file of several named `solid`s gets one label per solid name.
- glTF 2.0 (.gltf with its buffers, or .glb): one label per node that holds a mesh, named after the node (else its
  mesh, else node_N), with the nodes' transforms applied; triangle lists, strips and fans (points and lines
  are skipped).

Coordinates are read as metres. rfir's world frame is z up; glTF's is y up by its specification, so glTF is
turned to z up unless told otherwise (`up`): (x, y, z) -> (x, -z, y).
"""
from __future__ import annotations

import base64
import json
import re
import struct
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError

from .mesh_io import Mesh, read_ply_mesh

MESH_FORMATS = {".ply": "PLY", ".obj": "OBJ", ".stl": "STL", ".gltf": "glTF", ".glb": "GLB"}
FORMATS_WORDS = "PLY (.ply), OBJ (.obj), STL (.stl), glTF (.gltf, .glb)"


def read_mesh(path: str | Path, up: str | None = None) -> Mesh:
    """Read any of MESH_FORMATS by its extension; up: "z" or "y", the axis that points up in the file (None:
    the format's own convention: y for glTF, z for the rest). A y-up mesh is turned to z up."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise InputFileError(f"unknown mesh format {suffix or '(no extension)'!r}: rfir reads {FORMATS_WORDS}",
                             path=path)
    if up not in (None, "y", "z"):
        raise ConfigError(f"--up must be y or z, got {up!r}")
    if not path.is_file():
        raise InputFileError("file not found", path=path)
    if suffix == ".ply":
        mesh = read_ply_mesh(path)
    elif suffix == ".obj":
        mesh = read_obj_mesh(path)
    elif suffix == ".stl":
        mesh = read_stl_mesh(path)
    else:
        mesh = read_gltf_mesh(path)
    up = up or ("y" if suffix in (".gltf", ".glb") else "z")
    if up == "y":
        v = mesh.vertices
        mesh.vertices = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)
        mesh.notes.append("turned from y up to rfir's z up: (x, y, z) -> (x, -z, y)"
                          + (" (glTF is y up)" if suffix in (".gltf", ".glb") else ""))
    _check(mesh, path)
    return mesh


def _check(mesh: Mesh, path: Path) -> None:
    if len(mesh.faces) == 0:
        raise InputFileError("the mesh has no triangles", path=path)
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputFileError("vertex coordinates hold NaN or Inf", path=path)


def _labelled(vertices, faces, part_of_face: list[int] | None, names: list[str]) -> Mesh:
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if part_of_face is None:
        return Mesh(vertices, faces, None, {})
    return Mesh(vertices, faces, np.asarray(part_of_face, dtype=np.int64).reshape(-1),
                {i: n for i, n in enumerate(names)})


# ---------------------------------------------------------------------------------------------------- OBJ
def read_obj_mesh(path: Path) -> Mesh:
    """Wavefront OBJ text: `v`, `f` (indices 1-based or negative, `v/vt/vn` forms) and `o`/`g` part names."""
    vertices: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []
    part_of_face: list[int] = []
    names: list[str] = []
    current = -1          # -1: before any o/g
    named = False
    text = path.read_text(encoding="utf-8", errors="replace")
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        key, _, rest = line.partition(" ")
        rest = rest.strip()
        if key == "v":
            parts = rest.split()
            try:
                xyz = tuple(float(p) for p in parts[:3])
            except ValueError:
                xyz = ()
            if len(xyz) != 3:
                raise InputFileError(f"line {number}: a vertex needs three numbers, got {rest!r}", path=path)
            vertices.append(xyz)
        elif key in ("o", "g"):
            name = safe_label_name(rest) if rest else "unnamed"
            named = True
            if name not in names:
                names.append(name)
            current = names.index(name)
        elif key == "f":
            corners = []
            for token in rest.split():
                try:
                    index = int(token.split("/")[0])
                except ValueError:
                    raise InputFileError(f"line {number}: face corner {token!r} is not a vertex index",
                                         path=path) from None
                resolved = index - 1 if index > 0 else len(vertices) + index
                if index == 0 or not 0 <= resolved < len(vertices):
                    raise InputFileError(f"line {number}: face refers to vertex {index}, but "
                                         f"{len(vertices)} vertices are defined so far", path=path)
                corners.append(resolved)
            if len(corners) < 3:
                raise InputFileError(f"line {number}: a face needs at least three vertices", path=path)
            if current < 0:
                if "unnamed" not in names:
                    names.append("unnamed")
                current = names.index("unnamed")
            for k in range(1, len(corners) - 1):          # a polygon as a fan of triangles
                faces.append((corners[0], corners[k], corners[k + 1]))
                part_of_face.append(current)
    if not faces:
        raise InputFileError("OBJ has no faces ('f' lines)", path=path)
    return _labelled(vertices, faces, part_of_face if named else None, names)


# ---------------------------------------------------------------------------------------------------- STL
def read_stl_mesh(path: Path) -> Mesh:
    """Binary or ASCII STL; each facet its own three vertices (STL shares none)."""
    data = path.read_bytes()
    if len(data) >= 84:
        count = struct.unpack_from("<I", data, 80)[0]
        if len(data) == 84 + 50 * count and count > 0:
            rows = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                 count=count, offset=84)
            vertices = rows["v"].reshape(-1, 3).astype(np.float64)
            return _labelled(vertices, np.arange(len(vertices)).reshape(-1, 3), None, [])
    text = data.decode("ascii", errors="replace")
    if not text.lstrip().lower().startswith("solid"):
        raise InputFileError("not an STL file (neither a binary STL of the size its header states nor ASCII "
                             "starting with 'solid')", path=path)
    vertices, part_of_face, names = [], [], []
    current = 0
    corner_count = 0
    for number, raw in enumerate(text.splitlines(), start=1):
        words = raw.split()
        if not words:
            continue
        key = words[0].lower()
        if key == "solid":
            name = words[1] if len(words) > 1 else "unnamed"
            if name not in names:
                names.append(name)
            current = names.index(name)
        elif key == "vertex":
            try:
                vertices.append(tuple(float(w) for w in words[1:4]))
            except ValueError:
                vertices.append(())
            if len(vertices[-1]) != 3:
                raise InputFileError(f"line {number}: a vertex needs three numbers", path=path)
            corner_count += 1
        elif key == "endloop":
            if corner_count != 3:
                raise InputFileError(f"line {number}: a facet with {corner_count} vertices (STL facets have 3)",
                                     path=path)
            corner_count = 0
            part_of_face.append(current)
    if not vertices:
        raise InputFileError("STL has no facets", path=path)
    if len(vertices) != 3 * len(part_of_face):
        raise InputFileError("STL ends inside a facet (no 'endloop')", path=path)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    return _labelled(vertices, faces, part_of_face if len(names) > 1 else None, names)


# ---------------------------------------------------------------------------------------------------- glTF
_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def read_gltf_mesh(path: Path) -> Mesh:
    """glTF 2.0 JSON (.gltf, buffers as data URIs or files beside it) or binary (.glb): the meshes of the default
    scene's nodes with their world transforms, one label per node with a mesh."""
    data = path.read_bytes()
    binary = None
    try:
        if data[:4] == b"glTF":
            doc, binary = _glb_chunks(data, path)
        else:
            doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, struct.error) as exc:
        raise InputFileError(f"not a readable glTF file ({exc})", path=path) from None
    if not isinstance(doc, dict) or not str(doc.get("asset", {}).get("version", "")).startswith("2"):
        raise InputFileError("not a glTF 2.0 file (asset.version)", path=path)
    try:
        return _gltf_meshes(doc, binary, path)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputFileError(f"glTF file is incomplete or malformed ({type(exc).__name__}: {exc})", path=path) from None


def _glb_chunks(data: bytes, path: Path) -> tuple[dict, bytes | None]:
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2 or length > len(data):
        raise InputFileError(f"GLB version {version} or length {length} not readable (glTF 2.0 binary expected)",
                             path=path)
    offset, doc, binary = 12, None, None
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8: offset + 8 + size]
        if kind == 0x4E4F534A:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == 0x004E4942 and binary is None:
            binary = chunk
        offset += 8 + size
    if doc is None:
        raise InputFileError("GLB has no JSON chunk", path=path)
    return doc, binary


def _buffers(doc: dict, binary: bytes | None, path: Path) -> list[bytes]:
    out = []
    for i, buf in enumerate(doc.get("buffers", [])):
        uri = buf.get("uri")
        if uri is None:
            if binary is None:
                raise InputFileError(f"buffer {i} has no uri and the file no binary chunk", path=path)
            out.append(binary)
        elif uri.startswith("data:"):
            out.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            from urllib.parse import unquote

            file = path.parent / unquote(uri)
            if not file.is_file():
                raise InputFileError(f"buffer file {uri!r} not found beside the glTF file", path=path)
            out.append(file.read_bytes())
    return out


def _accessor(doc: dict, buffers: list[bytes], index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    if "sparse" in acc:
        raise ValueError(f"accessor {index} is sparse (not supported)")
    width = _WIDTH[acc["type"]]
    dtype = np.dtype(_COMPONENTS[acc["componentType"]])
    count = int(acc["count"])
    if "bufferView" not in acc:
        return np.zeros((count, width), dtype)
    view = doc["bufferViews"][acc["bufferView"]]
    buf = buffers[view["buffer"]]
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    stride = int(view.get("byteStride", 0)) or dtype.itemsize * width
    if count == 0:
        return np.zeros((0, width), dtype)
    end = start + stride * (count - 1) + dtype.itemsize * width
    if end > len(buf):
        raise ValueError(f"accessor {index} reads past the end of its buffer")
    raw = np.frombuffer(buf, dtype=np.uint8, count=end - start, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, dtype.itemsize * width), strides=(stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(count, width)


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T     # stored column-major
    t = np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64)
    x, y, z, w = np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
    s = np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * s[None, :]
    m[:3, 3] = t
    return m


def _triangles(mode: int, idx: np.ndarray) -> np.ndarray:
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5:                                                    # strip: every other one flipped
        tri = np.stack([idx[:-2], idx[1:-1], idx[2:]], axis=1) if len(idx) >= 3 else np.zeros((0, 3), idx.dtype)
        tri[1::2] = tri[1::2][:, [1, 0, 2]]
        return tri
    if mode == 6:                                                    # fan
        if len(idx) < 3:
            return np.zeros((0, 3), idx.dtype)
        return np.stack([np.full(len(idx) - 2, idx[0]), idx[1:-1], idx[2:]], axis=1)
    return np.zeros((0, 3), idx.dtype)                               # points, lines: no surface


def _gltf_meshes(doc: dict, binary: bytes | None, path: Path) -> Mesh:
    buffers = _buffers(doc, binary, path)
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    if scenes:
        roots = scenes[int(doc.get("scene", 0))].get("nodes", [])
    else:
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    vertices, faces, part_of_face, names = [], [], [], []
    offset = 0
    stack = [(int(r), np.eye(4), 0) for r in reversed(roots)]
    while stack:
        index, parent, depth = stack.pop()
        if depth > 64:
            raise ValueError("node hierarchy deeper than 64 (a cycle?)")
        node = nodes[index]
        world = parent @ _node_matrix(node)
        if "mesh" in node:
            mesh = doc["meshes"][node["mesh"]]
            label = len(names)
            names.append(safe_label_name(str(node.get("name") or mesh.get("name") or f"node_{index}")))
            for prim in mesh.get("primitives", []):
                pos = _accessor(doc, buffers, prim["attributes"]["POSITION"])
                if pos.dtype.kind != "f":
                    raise ValueError("positions that are not floats (quantised meshes) are not supported")
                pos = pos.astype(np.float64) @ world[:3, :3].T + world[:3, 3]
                idx = (_accessor(doc, buffers, prim["indices"]).reshape(-1).astype(np.int64) if "indices" in prim
                       else np.arange(len(pos), dtype=np.int64))
                if len(idx) and (idx.min() < 0 or idx.max() >= len(pos)):
                    raise ValueError("triangle indices outside the primitive's positions")
                tri = _triangles(int(prim.get("mode", 4)), idx)
                if np.linalg.det(world[:3, :3]) < 0:                  # a mirroring transform turns the winding
                    tri = tri[:, [0, 2, 1]]
                vertices.append(pos)
                faces.append(tri + offset)
                part_of_face.extend([label] * len(tri))
                offset += len(pos)
        stack.extend((int(c), world, depth + 1) for c in reversed(node.get("children", [])))
    if not faces or sum(len(f) for f in faces) == 0:
        raise InputFileError("glTF scene has no triangles", path=path)
    return _labelled(np.concatenate(vertices), np.concatenate(faces), part_of_face, names)


def safe_label_name(name: str) -> str:
    """A label name without spaces or characters other than letters, digits, '_', '-' and '.'."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name.strip()) or "unnamed"
