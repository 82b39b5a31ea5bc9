"""Reading, writing and validating rfir artifacts (HDF5). The only module that imports h5py.

Writes go to a temporary file in the target's folder and are renamed into place, so a crash or a
kill never leaves a half-written file at the target path, nor damages an earlier artifact there.

While a command runs (`begin_command` .. `end_command`, set up by the CLI's callback), no output is written
over a file the command read as an input (`note_input`: read_artifact, Provenance.add_input), nor, without
the global `--force`, over an existing file of another kind; commands call `check_output` before any work,
and write_artifact checks again before it writes. What the command read and wrote is kept in output_guard.py.
"""
from __future__ import annotations

import functools
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import h5py
import numpy as np

from . import __version__, output_guard
from .errors import InputFileError, SchemaError
from .output_guard import _key, note_input, note_output
from .output_guard import begin_command, end_command  # noqa: F401 - also artifacts' names (main.py, tests)
from .provenance import Provenance
from .schema import SCHEMA_MAJOR, SCHEMA_VERSION, FieldSpec, KindSpec, get_kind

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_DTYPE_CHECK = {
    "float": lambda d: d.kind == "f",
    "int": lambda d: d.kind in "iu",
    "complex": lambda d: d.kind == "c",
    "uint8": lambda d: d == np.uint8,
    "bool": lambda d: d.kind == "b",
    "str": lambda d: d.kind in "OSU",
}


@dataclass
class Artifact:
    """An artifact loaded into memory.

    data: dataset path ("group/name") -> numpy array (strings come back as str arrays).
    attrs: root attributes other than kind/schema_version/producer/created.
    free: free-form groups: group path -> {dataset name -> array}, plus "<group>@attrs" -> dict.
    """

    path: Path
    kind: str
    schema_version: str
    producer: str
    created: str
    attrs: dict
    data: dict[str, np.ndarray]
    provenance: Provenance
    free: dict = field(default_factory=dict)

    def get(self, name: str, default=None):
        return self.data.get(name, default)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def free_for_write(self) -> dict:
        """The free groups in write_artifact's layout: group -> {name: array, ..., "@attrs": dict}
        (copies of the dicts; the arrays are shared), so a stage can pass an input's groups on."""
        out = {}
        for group, content in self.free.items():
            if group.endswith("@attrs"):
                continue
            out[group] = dict(content)
            if self.free.get(group + "@attrs"):
                out[group]["@attrs"] = dict(self.free[group + "@attrs"])
        return out


def _existing_kind(path: Path) -> str | None:
    """The kind of the rfir artifact at `path`; "" for any other existing file (or folder)."""
    if path.is_dir():
        return ""
    try:
        with open(path, "rb") as handle:
            if handle.read(8) != _HDF5_SIGNATURE:
                return ""
        with h5py.File(path, "r") as h5:
            found = h5.attrs.get("kind")
    except (OSError, RuntimeError, ValueError, KeyError, TypeError):
        return ""
    if isinstance(found, bytes):
        found = found.decode(errors="replace")
    return "" if found is None else str(found)


def check_output(path: str | Path | None, kind: str | None = None, inputs: Iterable = ()) -> None:
    """Refuse, with one line (InputFileError), an output `path` that would replace one of the command's inputs
    (`inputs` here, or any noted so far; even with --force) or, without --force, an existing file of another
    kind: for kind = an artifact kind, anything but an rfir artifact of that kind (an artifact of the same
    kind is replaced: a rerun); for kind None (a PNG, JSON, CSV, TIFF or PLY beside an artifact), an HDF5
    file. Call it before any work; the paths in `inputs` are noted as inputs."""
    for p in inputs:
        if p is not None:
            note_input(p)
    if path is None:
        return
    path = Path(path)
    key = _key(path)
    named = {_key(p) for p in inputs if p is not None}
    if key in named or (output_guard.GUARD.active and key in output_guard.GUARD.inputs):
        raise InputFileError("is an input of this command; refusing to write over it (choose another output name)",
                             path=path)
    if path.is_dir():
        raise InputFileError("is a folder; refusing to write a file there (choose another output name)", path=path)
    if output_guard.GUARD.force or key in output_guard.GUARD.written or not (path.exists() or path.is_symlink()):
        return
    found = _existing_kind(path)
    if kind is None:
        if found or _is_hdf5(path):
            what = f"an rfir '{found}' artifact" if found else "an HDF5 file"
            raise InputFileError(f"exists and is {what}; refusing to replace it (pass --force or choose another "
                                 "name)", path=path)
        return
    if found == kind:
        return
    what = f"an rfir '{found}' artifact, not '{kind}'" if found else "not an rfir artifact"
    raise InputFileError(f"exists and is {what}; refusing to replace it (pass --force or choose another name)",
                         path=path)


def _is_hdf5(path: Path) -> bool:
    try:
        with open(path, "rb") as handle:
            return handle.read(8) == _HDF5_SIGNATURE
    except OSError:
        return False


def _utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _check_array(spec: FieldSpec, array: np.ndarray, dims: dict[str, int], where: str) -> list[str]:
    """Return the problems of one field's array against its spec (dims is filled as symbols bind)."""
    problems = []
    if not _DTYPE_CHECK[spec.dtype](array.dtype):
        problems.append(f"{where}: dataset '{spec.name}' has dtype {array.dtype}, expected {spec.dtype}")
        return problems
    if array.ndim != len(spec.shape):
        problems.append(f"{where}: dataset '{spec.name}' has shape {array.shape}, expected {_shape_text(spec.shape)}")
        return problems
    for size, want in zip(array.shape, spec.shape):
        if isinstance(want, int):
            if size != want:
                problems.append(f"{where}: dataset '{spec.name}' has shape {array.shape}, expected {_shape_text(spec.shape)}")
                break
        elif dims.setdefault(want, size) != size:
            problems.append(f"{where}: dataset '{spec.name}' has {want}={size} but another field has {want}={dims[want]}")
            break
    if spec.finite and spec.dtype in ("float", "complex") and array.size and not np.all(np.isfinite(array)):
        bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
        problems.append(f"{where}: dataset '{spec.name}' holds {bad} NaN or Inf values")
    return problems


def _shape_text(shape: tuple) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ")"


def check_data(kind: str, data: Mapping[str, np.ndarray], attrs: Mapping, where: str) -> list[str]:
    """All schema problems of in-memory data for `kind` (empty list when valid)."""
    spec = get_kind(kind)
    if spec.retired and spec.retired[0] not in data:
        return [f"{where}: {spec.retired[1]}"]
    problems, dims = [], {}
    for f in spec.fields:
        if f.name not in data:
            if f.required:
                problems.append(f"{where}: missing required dataset '{f.name}' for kind '{kind}'")
            continue
        problems += _check_array(f, np.asarray(data[f.name]), dims, where)
    for name in data:
        if spec.field(name) is None and not _in_free_group(spec, name):
            problems.append(f"{where}: dataset '{name}' is not part of kind '{kind}'")
    for key in spec.required_attrs:
        if key not in attrs:
            problems.append(f"{where}: missing required attribute '{key}' for kind '{kind}'")
    return problems + _check_attrs(spec, attrs, where)


def _check_attrs(spec: KindSpec, attrs: Mapping, where: str) -> list[str]:
    """Problems of the optional root attributes of `spec` that are present (types, choices, patterns,
    and each `table:` antenna's table attributes, of one length)."""
    problems = []
    for a in spec.optional_attrs:
        if a.name not in attrs:
            continue
        value = attrs[a.name]
        value = value.decode(errors="replace") if isinstance(value, bytes) else value
        if a.dtype == "str":
            if not isinstance(value, str):
                problems.append(f"{where}: attribute '{a.name}' is {value!r}, expected text")
            elif a.choices and value not in a.choices:
                problems.append(f"{where}: attribute '{a.name}' is {value!r}, expected one of {', '.join(a.choices)}")
            elif a.pattern and not re.fullmatch(a.pattern, value):
                problems.append(f"{where}: attribute '{a.name}' is {value!r}, not valid ({a.doc.split(';')[0]})")
            elif value.startswith("table:"):
                sizes = {np.size(attrs[k]) if k in attrs else -1 for k in (f"{a.name}_table_deg", f"{a.name}_table_gain_dbi")}
                if -1 in sizes or len(sizes) != 1 or sizes.pop() < 2:
                    problems.append(f"{where}: attribute '{a.name}' is a table but {a.name}_table_deg / "
                                    f"{a.name}_table_gain_dbi are missing or of different lengths")
            continue
        array = np.asarray(value)
        if array.dtype.kind not in "iuf" or array.ndim != (1 if a.dtype == "float[]" else 0) \
                or not np.all(np.isfinite(array)):
            want = "a 1-D array of finite numbers" if a.dtype == "float[]" else "a finite number"
            problems.append(f"{where}: attribute '{a.name}' is {_short_repr(value)}, expected {want}")
    return problems


def _short_repr(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _in_free_group(spec: KindSpec, name: str) -> bool:
    return any(name == g or name.startswith(g + "/") for g in spec.free_groups)


def _to_h5(array: np.ndarray, spec: FieldSpec | None):
    array = np.asarray(array)
    if (spec is not None and spec.dtype == "str") or array.dtype.kind in "OU":
        return np.asarray([str(s) for s in array.ravel()], dtype=h5py.string_dtype()).reshape(array.shape)
    return array


def write_artifact(path: str | Path, kind: str, data: Mapping[str, np.ndarray], *,
                   attrs: Mapping | None = None, provenance: Provenance | None = None,
                   free: Mapping[str, Mapping] | None = None) -> Path:
    """Validate and write an artifact atomically.

    data: dataset path -> array for the kind's fields; free: free-form group path -> {name: array}
    (e.g. network weights under "model"), group attributes under the key "@attrs".
    Raises SchemaError (naming the field) if the data breaks the schema; nothing is written then.
    """
    path = Path(path)
    if output_guard.GUARD.active:   # the last line of defence; commands call check_output before any work
        check_output(path, kind)
    attrs = dict(attrs or {})
    problems = check_data(kind, data, attrs, str(path))
    if problems:
        raise SchemaError("refusing to write invalid artifact: " + "; ".join(p.split(": ", 1)[1] for p in problems[:3]),
                          path=path)
    spec = get_kind(kind)
    for group in free or {}:
        if not _in_free_group(spec, group):
            raise SchemaError(f"group '{group}' is not a free-form group of kind '{kind}'", path=path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.partial-{os.getpid()}"
    provenance = provenance or Provenance(stage="unknown")
    try:
        with h5py.File(tmp, "w") as h5:
            h5.attrs.update({"kind": kind, "schema_version": SCHEMA_VERSION,
                             "producer": f"rfir {__version__} ({provenance.stage})", "created": _utc_now()})
            for key, value in attrs.items():
                h5.attrs[key] = value
            for name, array in data.items():
                f = spec.field(name)
                ds = h5.create_dataset(name, data=_to_h5(array, f))
                if f is not None:
                    ds.attrs["unit"] = f.unit
                    if f.frame:
                        ds.attrs["frame"] = f.frame
            for group, content in (free or {}).items():
                g = h5.require_group(group)
                for name, value in content.items():
                    if name == "@attrs":
                        g.attrs.update(value)
                    else:
                        g.create_dataset(name, data=_to_h5(value, None))
            h5.require_group("provenance").attrs.update(provenance.to_attrs())
        os.replace(tmp, path)
        note_output(path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _damaged_as_error(read):
    """Turn whatever h5py raises on a truncated or damaged file (OSError, RuntimeError, KeyError,
    ValueError, TypeError, by where the damage sits) into one InputFileError naming the file."""

    @functools.wraps(read)
    def wrapper(path, *args, **kwargs):
        try:
            return read(path, *args, **kwargs)
        except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
            detail = (str(exc).splitlines() or [type(exc).__name__])[0].split(";")[0]
            raise InputFileError(f"cannot read HDF5 data (truncated or damaged): {detail}", path=path) from None

    return wrapper


def _open(path: Path) -> h5py.File:
    if not path.exists():
        raise InputFileError("file not found", path=path)
    if path.is_dir():
        raise InputFileError("is a folder, expected an HDF5 artifact file", path=path)
    with open(path, "rb") as handle:
        if handle.read(8) != _HDF5_SIGNATURE:
            raise InputFileError("not an HDF5 file (wrong signature)", path=path)
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(f"cannot read HDF5 file (truncated or damaged): {str(exc).split(';')[0]}", path=path) from None


def _header(h5: h5py.File, path: Path, kind: str | Iterable[str] | None) -> tuple[str, str]:
    found = h5.attrs.get("kind")
    if found is None:
        raise SchemaError("not an rfir artifact (no 'kind' attribute)", path=path)
    found = str(found)
    wanted = [kind] if isinstance(kind, str) else list(kind or [])
    if wanted and found not in wanted:
        raise SchemaError(f"artifact of kind '{found}', expected {' or '.join(repr(w) for w in wanted)}", path=path)
    try:
        get_kind(found)
    except KeyError as exc:
        raise SchemaError(str(exc.args[0]), path=path) from None
    version = str(h5.attrs.get("schema_version", ""))
    try:
        major = int(version.split(".")[0])
    except ValueError:
        raise SchemaError(f"bad schema_version {version!r}", path=path) from None
    if major != SCHEMA_MAJOR:
        raise SchemaError(f"schema version {version} is not supported (this rfir reads {SCHEMA_MAJOR}.x)", path=path)
    return found, version


def _read_dataset(ds: h5py.Dataset) -> np.ndarray:
    if h5py.check_string_dtype(ds.dtype) is not None:
        return np.asarray(ds.asstr()[()], dtype=object).astype(str)
    return ds[()]


@_damaged_as_error
def read_artifact(path: str | Path, kind: str | Iterable[str] | None = None) -> Artifact:
    """Load and validate an artifact. Raises InputFileError / SchemaError with one clear line."""
    path = Path(path)
    note_input(path)
    with _open(path) as h5:
        try:
            found, version = _header(h5, path, kind)
            spec = get_kind(found)
            data, free = {}, {}
            for f in spec.fields:
                if f.name in h5:
                    data[f.name] = _read_dataset(h5[f.name])
            for group in spec.free_groups:
                if group in h5:
                    free[group] = {n: _read_dataset(d) for n, d in h5[group].items() if isinstance(d, h5py.Dataset)}
                    free[group + "@attrs"] = dict(h5[group].attrs)
            root = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()
                    if k not in ("kind", "schema_version", "producer", "created")}
            prov = Provenance.from_attrs(dict(h5["provenance"].attrs)) if "provenance" in h5 else Provenance(stage="")
            producer, created = str(h5.attrs.get("producer", "")), str(h5.attrs.get("created", ""))
        except OSError as exc:
            raise InputFileError(f"cannot read HDF5 data (truncated or damaged): {exc}", path=path) from None
    problems = check_data(found, data, root, str(path))
    if problems:
        raise SchemaError(problems[0].split(": ", 1)[1], path=path)
    return Artifact(path, found, version, producer, created, root, data, prov, free)


@_damaged_as_error
def describe_artifact(path: str | Path) -> dict:
    """A summary for `rfir info`: header, provenance and every dataset with shape, dtype, unit."""
    path = Path(path)
    with _open(path) as h5:
        found, version = _header(h5, path, None)
        datasets = []

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and not name.startswith("provenance"):
                datasets.append({"name": name, "shape": tuple(obj.shape), "dtype": str(obj.dtype),
                                 "unit": str(obj.attrs.get("unit", "")), "frame": str(obj.attrs.get("frame", ""))})

        h5.visititems(visit)
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
        prov = Provenance.from_attrs(dict(h5["provenance"].attrs)) if "provenance" in h5 else None
    return {"path": str(path), "kind": found, "schema_version": version, "attrs": attrs,
            "datasets": datasets, "provenance": prov}


@_damaged_as_error
def validate_artifact(path: str | Path, kind: str | None = None) -> list[str]:
    """All problems of an artifact file (empty when valid); raises only for unreadable files."""
    path = Path(path)
    with _open(path) as h5:
        found, _ = _header(h5, path, kind)
        spec = get_kind(found)
        data = {f.name: _read_dataset(h5[f.name]) for f in spec.fields if f.name in h5}
        root = dict(h5.attrs)
        problems = check_data(found, data, root, str(path))

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and not name.startswith("provenance") and spec.field(name) is None \
                    and not _in_free_group(spec, name):
                problems.append(f"{path}: dataset '{name}' is not part of kind '{found}'")

        h5.visititems(visit)
        if "provenance" not in h5:
            problems.append(f"{path}: missing /provenance group")
    return problems
