"""Artifacts: round trip, atomic writes, and every kind of bad file gives one clear SchemaError/InputFileError."""
import h5py
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact, validate_artifact, write_artifact
from rfir_core.errors import InputFileError, SchemaError
from rfir_core.provenance import Provenance
from rfir_core.schema import KINDS, SCHEMA_VERSION


def test_round_trip_keeps_values_units_and_provenance(measurements_file, measurement_data):
    art = read_artifact(measurements_file, "measurements")
    data = measurement_data()
    for name, value in data.items():
        np.testing.assert_array_equal(art[name], value)
    assert art.attrs == {"task": "rssi", "scene": "unit"}
    assert art.schema_version == SCHEMA_VERSION
    assert art.provenance.stage == "test"
    assert "rfir" in art.provenance.versions
    with h5py.File(measurements_file) as h5:
        assert h5["tx_pos"].attrs["unit"] == "m" and h5["tx_pos"].attrs["frame"] == "world"


def test_strings_and_free_groups_round_trip(tmp_path, measurement_data):
    data = {"image_names": np.array(["a.png", "b.png"]), "intrinsics": np.tile(np.eye(3), (2, 1, 1)),
            "world_from_camera": np.tile(np.eye(4), (2, 1, 1)), "image_size": np.array([[640, 480]] * 2)}
    path = write_artifact(tmp_path / "c.h5", "cameras", data, attrs={"scene": "s"})
    art = read_artifact(path, "cameras")
    assert list(art["image_names"]) == ["a.png", "b.png"]
    rf = tmp_path / "m.h5"
    write_artifact(rf, "measurements", measurement_data(), attrs={"task": "rcs", "scene": "s"},
                   free={"simulator": {"@attrs": {"backend": "po"}, "weights": np.arange(3.0)}})
    art = read_artifact(rf)
    assert art.free["simulator@attrs"]["backend"] == "po"
    np.testing.assert_array_equal(art.free["simulator"]["weights"], np.arange(3.0))


def test_every_kind_documents_units():
    for spec in KINDS.values():
        for field in spec.fields:
            assert field.doc, f"{spec.kind}/{field.name} has no doc"
            assert field.dtype in ("float", "int", "complex", "uint8", "bool", "str")


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("freq_hz"), "missing required dataset 'freq_hz'"),
    (lambda d: d.update(path_gain_db=np.full((5, 2), np.nan)), "NaN or Inf"),
    (lambda d: d.update(rx_pos=np.zeros((4, 3))), "L=4"),
    (lambda d: d.update(tx_pos=np.zeros((5, 2))), "expected (L, 3)"),
    (lambda d: d.update(extra=np.zeros(3)), "not part of kind"),
])
def test_invalid_data_is_refused_before_writing(tmp_path, mutate, message, measurement_data):
    data = measurement_data()
    mutate(data)
    target = tmp_path / "bad.h5"
    with pytest.raises(SchemaError, match=message.replace("(", r"\(").replace(")", r"\)")):
        write_artifact(target, "measurements", data, attrs={"task": "rssi", "scene": "s"})
    assert not target.exists() and not list(tmp_path.iterdir())


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputFileError, match="file not found"):
        read_artifact(tmp_path / "none.h5")
    with pytest.raises(InputFileError, match="is a folder"):
        read_artifact(tmp_path)


def test_non_hdf5_and_truncated(tmp_path, measurements_file):
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    with pytest.raises(InputFileError, match="not an HDF5 file"):
        read_artifact(text)
    blob = measurements_file.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(InputFileError, match="truncated or damaged"):
        read_artifact(cut)


def test_wrong_kind_and_unknown_version(measurements_file):
    with pytest.raises(SchemaError, match="kind 'measurements', expected 'calib'"):
        read_artifact(measurements_file, "calib")
    with h5py.File(measurements_file, "a") as h5:
        h5.attrs["schema_version"] = "2.0.0"
    with pytest.raises(SchemaError, match="schema version 2.0.0 is not supported"):
        read_artifact(measurements_file)


def test_hand_written_file_with_nan_or_missing_dataset(measurements_file):
    with h5py.File(measurements_file, "a") as h5:
        h5["path_gain_db"][0, 0] = np.inf
    assert any("NaN or Inf" in p for p in validate_artifact(measurements_file))
    with pytest.raises(SchemaError, match="NaN or Inf"):
        read_artifact(measurements_file)
    with h5py.File(measurements_file, "a") as h5:
        del h5["rx_pos"]
    assert any("missing required dataset 'rx_pos'" in p for p in validate_artifact(measurements_file))


def test_rewrite_replaces_atomically(tmp_path, measurements_file, measurement_data):
    data = measurement_data(links=7)
    write_artifact(measurements_file, "measurements", data, attrs={"task": "rssi", "scene": "unit"})
    assert read_artifact(measurements_file)["tx_pos"].shape == (7, 3)
    assert [p.name for p in tmp_path.iterdir()] == ["m.h5"]
    assert Provenance.from_attrs(Provenance(stage="x", extra={"a": 1}).to_attrs()).extra == {"a": 1}
