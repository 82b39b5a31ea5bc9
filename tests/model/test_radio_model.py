"""The radio-model interface and registry (rfir_stages.model.radio_model): each kind loaded from its artifact,
checked against closed forms (a conducting plate's broadside RCS; free space through a room whose materials are
air), refusals in one line, materials, save, and a new kind added by one registration."""
import math

import numpy as np
import pytest
import torch

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.errors import ConfigError, InputFileError, SchemaError
from rfir_core.physics.closed_forms import plate_rcs_broadside_m2
from rfir_stages import api
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.model import radio_model
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.physical import MaterialValues, PairSettings
from rfir_stages.model.radio_model import RadioModel, load_model, register_model_kind
from rfir_stages.model.surfels import surfel_areas
from rfir_stages.simulate.scenes import _merge, box, rect_xy, wall

C0 = 299_792_458.0
PLATE_M = 0.2
FREQ_HZ = 10e9


def _write_model(path, fields: dict, mats: MaterialValues, material_of: np.ndarray, names: list, freq_hz: float,
                 task: str, model_attrs: dict | None = None, label_names=None):
    """An rf artifact of the physical model with the given materials (rfir_stages.model.artifact.physical_fields)."""
    t = lambda k: torch.as_tensor(np.asarray(fields[f"gaussians/{k}"], np.float64))  # noqa: E731
    data = {k: v for k, v in fields.items() if k.startswith("gaussians/")}
    model, attrs = physical_fields(mats, torch.as_tensor(material_of),
                                   surfel_areas(t("means"), t("log_scales"), t("rotations"), t("normals")),
                                   np.array([freq_hz]), PairSettings(), names, 0.0)
    data.update(model)
    data["rf/freq_hz"] = np.array([freq_hz])
    attrs.update({"antenna_kind": "isotropic", **(model_attrs or {})})
    root = {"task": task}
    if label_names is not None:
        root["label_names"] = np.asarray(label_names, dtype=object)
    return write_artifact(path, "rf", data, attrs=root, free={"model": {"@attrs": attrs}})


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """A 20 cm conducting square plate facing +x at the origin: the object RCS model of a metal."""
    v, f = wall((0.0, -PLATE_M / 2, -PLATE_M / 2), (0, 1, 0), (1, 0, 0), PLATE_M, PLATE_M)
    fields = gaussians_from_mesh(v, f, 0.01)
    g = len(fields["gaussians/means"])
    metal = MaterialValues(torch.tensor([1.0]), torch.tensor([1e7]), 0.0, torch.tensor([0.0]), None)
    return _write_model(tmp_path_factory.mktemp("plate") / "rf.h5", fields, metal, np.zeros(g, np.int64), ["metal"],
                        FREQ_HZ, "rcs")


def _room_fields():
    """A 4 x 3 x 2.5 m room with a table (a label each: floor, ceiling, four walls, table)."""
    parts = [rect_xy(0, 4, 0, 3, 0.0, up=True), rect_xy(0, 4, 0, 3, 2.5, up=False),
             wall((0, 0, 0), (0, 1, 0), (1, 0, 0), 3, 2.5), wall((4, 0, 0), (0, 1, 0), (-1, 0, 0), 3, 2.5),
             wall((0, 0, 0), (1, 0, 0), (0, 1, 0), 4, 2.5), wall((0, 3, 0), (1, 0, 0), (0, -1, 0), 4, 2.5),
             box((0.6, 0.6, 0.0), (1.4, 1.2, 0.7))]
    v, f = _merge(parts)
    labels = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)])
    return gaussians_from_mesh(v, f, 0.6, labels=labels)


@pytest.fixture(scope="module")
def air_room(tmp_path_factory):
    """The room model of a room whose every material is air (eps_r 1, sigma 1e-9 S/m, no diffuse share)."""
    fields = _room_fields()
    labels = np.asarray(fields["gaussians/labels"], np.int64)
    n = int(labels.max()) + 1
    # sigma exactly 0 gives NaN inside the room's coefficient tables; 1e-9 S/m is air for any purpose here
    air = MaterialValues(torch.ones(n), torch.full((n,), 1e-9), 1.0, torch.zeros(n), torch.full((n,), 0.1))
    names = ["floor", "ceiling", "wall_a", "wall_b", "wall_c", "wall_d", "table"]
    return _write_model(tmp_path_factory.mktemp("room") / "rf.h5", fields, air, labels, names, 2.4e9, "rssi",
                        {"model_kind": "rssi_physical"}, label_names=names)


def test_each_kind_is_loaded_from_its_artifact_and_the_other_quantity_is_refused(plate, air_room):
    obj, room = load_model(plate), load_model(air_room)
    assert (obj.kind, room.kind) == ("rcs_physical", "rssi_physical")
    assert obj.settings.__class__.__name__ == "PairSettings" and room.settings.__class__.__name__ == "RoomSettings"
    assert obj.geometry.num == len(read_artifact(plate)["gaussians/means"])
    with pytest.raises(SchemaError, match="holds an RCS model .* predict it with `rfir predict rcs`"):
        load_model(plate, quantity="rssi")
    with pytest.raises(SchemaError, match="holds an RSSI model .* predict it with `rfir predict rssi`"):
        load_model(air_room, quantity="rcs")


def test_object_model_gives_the_broadside_rcs_of_a_conducting_plate(plate):
    model = load_model(plate, quantity="rcs")
    rcs = api.predict_rcs(model, [0.0, 10.0], [30.0], [FREQ_HZ])        # [R, A, F] dBsm
    expected = 10 * math.log10(plate_rcs_broadside_m2(PLATE_M ** 2, FREQ_HZ))
    assert abs(rcs[0, 0, 0] - expected) < 0.5, (rcs[0, 0, 0], expected)
    # 10 degrees off broadside the plate's PO pattern, sinc^2(k L sin(theta)), is in a deep lobe far below its peak
    assert rcs[0, 1, 0] < expected - 15


def test_room_model_whose_materials_are_air_predicts_free_space(air_room):
    model = load_model(air_room, quantity="rssi")
    rng = np.random.default_rng(3)
    tx = rng.uniform([0.5, 0.5, 1.0], [3.5, 2.5, 2.0], (12, 3))
    rx = rng.uniform([0.5, 0.5, 1.0], [3.5, 2.5, 2.0], (12, 3))
    pg = model.predict(tx, rx)                                          # [N, 1] dB at the fitted 2.4 GHz
    friis = 20 * np.log10(C0 / 2.4e9 / (4 * np.pi * np.linalg.norm(rx - tx, axis=1)))
    assert pg.shape == (12, 1)
    np.testing.assert_allclose(pg[:, 0], friis, atol=1e-3)
    # at other frequencies from the same traced paths: Friis scales with the wavelength
    pg2 = model.predict(tx, rx, [2.4e9, 5.8e9])
    np.testing.assert_allclose(pg2[:, 1] - pg2[:, 0], 20 * np.log10(2.4 / 5.8), atol=1e-3)
    with pytest.raises(ConfigError, match="outside .* GHz, where this model's material laws hold"):
        model.predict(tx, rx, [500e9])


def test_materials_name_each_fitted_value_and_save_writes_a_model_that_predicts_the_same(plate, tmp_path):
    model = load_model(plate)
    metal = model.materials()["metal"]
    gamma = metal.pop("gamma_normal_abs")
    assert metal == {"eps_r": 1.0, "sigma_1ghz_s_per_m": 1e7, "sigma_exponent": 0.0, "thickness_m": 0.0,
                     "scattering": 0.0, "gaussians": model.geometry.num}        # no ranges stored: none given
    # |Gamma(0)| of a half-space, (1 - n) / (1 + n) with n^2 = eps_r - j sigma / (omega eps0)
    f = model.fitted_freqs_hz[0]
    n = np.sqrt(1.0 - 1j * 1e7 / (2 * np.pi * f * 8.8541878128e-12))
    assert gamma == pytest.approx(abs((1 - n) / (1 + n)), abs=1e-9)
    copy = load_model(model.save(tmp_path / "copy.h5"))
    tx = np.array([[3.0, 0.0, 0.0], [0.0, 3.0, 0.5]])
    np.testing.assert_array_equal(copy.predict(tx, tx), model.predict(tx, tx))
    with pytest.raises(InputFileError, match="refusing to write over it"):
        model.save(plate)


def test_a_new_model_kind_is_one_class_and_one_registration(plate, tmp_path, monkeypatch):
    class FreeSpace(RadioModel):
        """Friis between isotropic antennas: the smallest kind there is."""

        kind = "free_space"

        def _path_gain_db(self, tx, rx, freqs, progress, advance, chunk_links, physics_only):
            d = np.linalg.norm(rx - tx, axis=1)[:, None]
            out = 20 * np.log10(C0 / freqs[None] / (4 * np.pi * d))
            return out, (out if physics_only else None)

    monkeypatch.setattr(radio_model, "_KINDS", dict(radio_model._KINDS))
    register_model_kind("free_space", FreeSpace, quantity="rssi")
    rf = read_artifact(plate)
    rf.free["model@attrs"] = {**rf.free["model@attrs"], "model_kind": "free_space"}
    model = load_model(rf, quantity="rssi")
    assert isinstance(model, FreeSpace)
    pg = model.predict([0.0, 0.0, 0.0], [[10.0, 0.0, 0.0]], [1e9, 2e9])
    np.testing.assert_allclose(pg[0], [20 * np.log10(C0 / f / (40 * np.pi)) for f in (1e9, 2e9)])
    rf.free["model@attrs"]["model_kind"] = "not_registered"
    with pytest.raises(SchemaError, match="kind 'not_registered', which rfir cannot predict"):
        load_model(rf)


def test_bad_links_are_refused_in_one_line(plate):
    model = load_model(plate)
    with pytest.raises(Exception, match=r"\[N, 3\] positions in metres"):
        model.predict(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(Exception, match="positive numbers in hertz"):
        model.predict(np.zeros((1, 3)), np.ones((1, 3)), [-1.0])
