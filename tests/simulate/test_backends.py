"""rcs backends (Sionna RT vs physical optics) and the parallel Sionna path (simulate.workers)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, validate_artifact
from rfir_cli.context import GlobalOptions
from rfir_core.errors import ConfigError, StageError
from rfir_core.progress import NullProgress
from rfir_core.physics.antennas import horn_boresight_gain
from rfir_stages.simulate.po_backend import simulate_monostatic_po
from rfir_stages.simulate.rcs import RadarGrid, aspect_grid, object_radius
from rfir_stages.simulate.scenes import SceneSpec, plate, rotate_z
from rfir_stages.simulate.settings import PoSettings, _defaults, parse_settings
from rfir_stages.simulate.solve import PhysicsEffects, rcs_dbsm_from_gain

G0 = horn_boresight_gain(40.0)
SPECULAR_ONLY = PhysicsEffects(max_depth=1, diffuse=False, refraction=False, samples_per_src=100_000,
                               combine="coherent")


def _config(**sections) -> dict:
    c = _defaults()
    for key, value in sections.items():
        c[key] = {**c[key], **value} if isinstance(value, dict) else value
    return c


def _sionna_rcs(spec, grid, freqs, tmp_path):
    pytest.importorskip("sionna.rt")
    from rfir_stages.simulate.radio_scene import load_radio_scene
    from rfir_stages.simulate.rcs import simulate_monostatic

    scene = load_radio_scene(spec, tmp_path / "radio", freqs[0])
    raw = simulate_monostatic(scene, grid, object_radius(spec), freqs, [np.array([f]) for f in freqs], SPECULAR_ONLY,
                              40.0, True, NullProgress(), "sionna")
    _, rng, _ = grid.links()
    return rcs_dbsm_from_gain(np.maximum(raw.power, 1e-30), rng, np.asarray(freqs), G0)


def _po_rcs(spec, grid, freqs, po=PoSettings()):
    raw, prov = simulate_monostatic_po(spec, grid, np.asarray(freqs), 40.0, po, NullProgress(), "po")
    _, rng, _ = grid.links()
    return rcs_dbsm_from_gain(raw.power, rng, np.asarray(freqs), G0), prov


def test_settings_backend_and_workers():
    s = parse_settings(_config(rcs_backend="PO", workers=1, po={"second_order": False, "sbr_spacing_m": 0.01}))
    assert s.rcs_backend == "po" and s.workers == 1
    assert not s.po.second_order and s.po.sbr_spacing_m == 0.01 and s.po.max_facet_edge_m is None
    assert parse_settings(_config()).rcs_backend == "sionna" and parse_settings(_config()).workers == 2
    with pytest.raises(ConfigError, match="rcs_backend"):
        parse_settings(_config(rcs_backend="mom"))
    with pytest.raises(ConfigError, match="workers"):
        parse_settings(_config(workers=0))


def test_po_quick_lego_artifact(tmp_path, check_quick_rcs_conventions):
    """--rcs-backend po: the same artifact schema and conventions as the Sionna backend."""
    from rfir_stages.simulate import run

    cfg = _config(photos=False, rcs_backend="po", measurement={"gain_offset_db": -2.0},
                  quick_sizes={"aspect_step_deg": 45.0, "ranges_m": [2.0, 4.0]})
    res = run("lego", tmp_path, cfg, quick=True)
    assert res.backends == {"rcs": "po"}
    path = res.measurements["rcs"]
    assert validate_artifact(path, "measurements") == []  # what `rfir check` runs
    art = read_artifact(path, "measurements")
    check_quick_rcs_conventions(art)
    d = art.data
    # rcs from the final path gain with the radar equation, as the Sionna backend does
    np.testing.assert_allclose(d["rcs_dbsm"], rcs_dbsm_from_gain(10 ** (d["path_gain_db"] / 10), d["range_m"],
                                                                 d["freq_hz"], G0), atol=1e-9)
    assert (d["rcs_dbsm"] < 30).all()
    sim = art.free["simulator@attrs"]
    assert sim["backend"] == "po" and sim["rcs_backend"] == "po" and sim["antenna_tx"] == "horn"
    assert sim["po.near_field"] and sim["po.second_order"] and sim["po.polarization"] == "V"
    assert sim["measurement.gain_offset_db"] == -2.0 and "physics.diffuse" not in sim
    assert '"rcs_backend": "po"' in art.provenance.to_attrs()["extra_json"]
    # the offset is applied to path gain (and so to rcs) exactly as for Sionna
    cfg["measurement"] = {**cfg["measurement"], "gain_offset_db": 0.0}
    clean = read_artifact(run("lego", tmp_path / "clean", cfg, quick=True).measurements["rcs"], "measurements").data
    np.testing.assert_allclose(d["path_gain_db"] - clean["path_gain_db"], -2.0, atol=1e-9)


def test_plate_normal_incidence_po_matches_sionna(tmp_path):
    """4 x 4 m metal plate at normal incidence through both backends' simulate code (horns, radar
    equation): within 1 dB (GO regime: plate >> Fresnel zone, docs/po.md)."""
    spec = plate(4.0)
    grid = RadarGrid(np.array([0.0]), np.array([2.0, 3.0]), np.zeros(3))
    freqs = [2.4e9, 5.8e9]
    po, _ = _po_rcs(spec, grid, freqs, PoSettings(second_order=False))
    sion = _sionna_rcs(spec, grid, freqs, tmp_path)
    go = 10 * np.log10(np.pi * np.array([2.0, 3.0]) ** 2)[:, None]
    print("PO", po.round(2), "Sionna", sion.round(2), "pi r^2", go.round(2))
    np.testing.assert_allclose(sion, np.broadcast_to(go, sion.shape), atol=0.1)
    np.testing.assert_allclose(po, sion, atol=1.0)


def test_broadside_at_same_aspect_in_both_backends(tmp_path):
    """A 0.5 m plate turned to face azimuth -30 deg: with the radar at azimuth -aspect both
    backends put its echo at aspect 30 deg (the plate is two-sided: 210 deg too); PO's side lobes
    are well below."""
    base = plate(0.5)
    obj = base.objects[0]
    obj.vertices = rotate_z(obj.vertices, math.radians(-30.0))
    spec = SceneSpec("plate", "object", [obj], base.bounds)
    grid = RadarGrid(aspect_grid(10.0), np.array([3.0]), np.zeros(3))
    po, _ = _po_rcs(spec, grid, [5.8e9], PoSettings(second_order=False))
    sion = _sionna_rcs(spec, grid, [5.8e9], tmp_path)
    assert int(np.argmax(po[:, 0])) in (3, 21) and int(np.argmax(sion[:, 0])) in (3, 21)
    assert abs(po[3, 0] - po[21, 0]) < 0.1 and sion[3, 0] > 10 and sion[21, 0] > 10
    assert po[3, 0] - np.delete(po[:, 0], [3, 21]).max() > 10 and np.delete(sion[:, 0], [3, 21]).max() < -50


def test_cli_po_backend_h_target(tmp_path):
    """`rfir simulate h-target OUT --rcs-backend po`: rcs and wideband artifacts (all frequencies in
    one PO call); echoes from the H's flat faces at multiples of 90 deg (as Sionna's glints), none
    between (the side faces at 0/180 give the larger PO echo at 3 m: the front face is wider than the
    Fresnel zone sqrt(lambda r) = 0.39 m, and its two uprights return out of phase)."""
    from rfir_cli.commands import simulate as cmd

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=["simulate.quick_sizes.aspect_step_deg=45",
                                           "simulate.quick_sizes.wideband_num_freqs=16"])

    cmd.register(app)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["simulate", "h-target", str(out), "--quick", "--no-photos",
                                      "--rcs-backend", "po"])
    assert result.exit_code == 0, result.output
    rcs = read_artifact(out / "measurements.h5", "measurements")
    wb = read_artifact(out / "measurements_wideband.h5", "measurements")
    assert rcs.free["simulator@attrs"]["backend"] == "po" and wb.free["simulator@attrs"]["backend"] == "po"
    assert wb.attrs["task"] == "wideband" and wb.data["path_gain_db"].shape == (8, 16)
    assert validate_artifact(out / "measurements_wideband.h5", "measurements") == []
    r = rcs.data["rcs_dbsm"][:, 1]  # 5.8 GHz, aspects 0, 45, ..., 315
    assert r[0::2].min() - r[1::2].max() > 20, r
    assert r[0] == pytest.approx(r[4], abs=0.05) and r[2] == pytest.approx(r[6], abs=0.05), r
    assert (out / "radio" / "h-target.xml").exists()


def test_parallel_workers_identical_to_in_process(tmp_path):
    """workers=2 ('spawn' processes, one Dr.Jit thread each) gives bit-identical arrays to workers=1."""
    pytest.importorskip("sionna.rt")
    from rfir_stages.simulate import run

    data = {}
    for w in (1, 2):
        cfg = _config(photos=False, workers=w, quick_sizes={"aspect_step_deg": 60.0})
        res = run("lego", tmp_path / f"w{w}", cfg, quick=True)
        art = read_artifact(res.measurements["rcs"], "measurements")
        assert art.free["simulator@attrs"]["workers"] == w
        data[w] = art.data
    for key in ("channel", "path_gain_db", "rcs_dbsm"):
        np.testing.assert_array_equal(data[1][key], data[2][key])


def test_parallel_worker_failure_is_a_stage_error(tmp_path):
    """A worker that cannot start (here: a missing scene file) raises StageError, it does not hang."""
    pytest.importorskip("sionna.rt")
    from rfir_stages.simulate.parallel import run_units

    units = [(0, 2.4e9, np.array([2.4e9]), np.arange(2))]
    with pytest.raises(StageError, match="worker"):
        run_units(units, {}, str(tmp_path / "missing.xml"), None, 2, 300.0, lambda u, r: None)
