"""No command writes over one of its inputs, nor (without --force) over an existing file of another kind.

Each refusal is one line naming the file, exit code 2, and leaves the file's bytes as they were.
"""
import numpy as np
from typer.testing import CliRunner

from rfir_core import artifacts
from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.errors import InputFileError
from rfir_cli.main import app
from rfir_stages.simulate.scenes import write_ply

runner = CliRunner()

CSV = ("tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db\n"
       "0,0,1,1,1,1,2.4e9,-50\n"
       "0,0,1,2,1,1,2.4e9,-55\n"
       "0,0,1,3,1,1,2.4e9,-58\n")


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_refused(result, path, *fragments):
    text = result.output.strip()
    assert result.exit_code == 2, text
    assert "Traceback" not in text
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert str(path) in text and "refusing" in text, text
    for fragment in fragments:
        assert fragment in text, text


def panel_ply(path):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return write_ply(path, v, f)


def test_import_csv_onto_its_own_csv_is_refused_even_with_force(tmp_path):
    csv = tmp_path / "x.csv"
    csv.write_text(CSV)
    before = csv.read_bytes()
    assert_refused(invoke("import", "csv", csv, "-o", csv), csv, "input of this command")
    assert csv.read_bytes() == before
    assert_refused(invoke("--force", "import", "csv", csv, "-o", csv), csv, "input of this command")
    assert csv.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]


def test_mesh_gaussians_onto_its_ply_is_refused_even_with_force(tmp_path):
    mesh = panel_ply(tmp_path / "room.ply")
    before = mesh.read_bytes()
    assert_refused(invoke("mesh-gaussians", mesh, "-o", mesh), mesh, "input of this command")
    assert mesh.read_bytes() == before
    assert_refused(invoke("--force", "mesh-gaussians", mesh, "-o", mesh), mesh, "input of this command")
    assert mesh.read_bytes() == before


def test_output_onto_an_artifact_of_another_kind_needs_force(tmp_path):
    csv = tmp_path / "x.csv"
    csv.write_text(CSV)
    mesh = panel_ply(tmp_path / "room.ply")
    scene = tmp_path / "scene.h5"
    r = invoke("mesh-gaussians", mesh, "-o", scene, "--spacing", "0.5")
    assert r.exit_code == 0, r.output
    before = scene.read_bytes()
    # measurements over a scene: refused, before any work, with the kinds named
    assert_refused(invoke("import", "csv", csv, "-o", scene), scene, "'scene' artifact, not 'measurements'",
                   "--force")
    assert scene.read_bytes() == before
    r = invoke("--force", "import", "csv", csv, "-o", scene)
    assert r.exit_code == 0, r.output
    assert read_artifact(scene).kind == "measurements"


def test_output_onto_a_file_that_is_no_artifact_needs_force(tmp_path):
    mesh = panel_ply(tmp_path / "room.ply")
    notes = tmp_path / "notes.h5"
    notes.write_text("my notes, not an artifact\n")
    assert_refused(invoke("mesh-gaussians", mesh, "-o", notes), notes, "not an rfir artifact", "--force")
    assert notes.read_text() == "my notes, not an artifact\n"
    r = invoke("--force", "mesh-gaussians", mesh, "-o", notes, "--spacing", "0.5")
    assert r.exit_code == 0, r.output
    assert read_artifact(notes).kind == "scene"


def test_output_onto_a_folder_is_refused_even_with_force(tmp_path):
    mesh = panel_ply(tmp_path / "room.ply")
    folder = tmp_path / "scene.h5"
    folder.mkdir()
    assert_refused(invoke("--force", "mesh-gaussians", mesh, "-o", folder), folder, "is a folder")
    assert folder.is_dir() and not list(folder.iterdir())


def test_rerun_onto_an_artifact_of_the_same_kind_is_allowed(tmp_path):
    csv = tmp_path / "x.csv"
    csv.write_text(CSV)
    out = tmp_path / "m.h5"
    for _ in range(2):
        r = invoke("import", "csv", csv, "-o", out)
        assert r.exit_code == 0, r.output
    assert len(read_artifact(out, "measurements")["tx_pos"]) == 3


def test_outside_a_command_the_library_is_not_guarded_and_the_guard_ends(tmp_path):
    # a command ends its guard: a later library write over a file that command read is the caller's business
    csv = tmp_path / "x.csv"
    csv.write_text(CSV)
    out = tmp_path / "m.h5"
    assert invoke("import", "csv", csv, "-o", out).exit_code == 0
    art = read_artifact(out)
    write_artifact(out, "measurements", art.data, attrs=art.attrs)
    # inside a command, a noted input is refused by write_artifact itself (the last line of defence)
    artifacts.begin_command(force=True)
    try:
        read_artifact(out)
        before = out.read_bytes()
        try:
            write_artifact(out, "measurements", art.data, attrs=art.attrs)
            raise AssertionError("write over an input was not refused")
        except InputFileError as exc:
            assert "input of this command" in str(exc)
        assert out.read_bytes() == before
    finally:
        artifacts.end_command()


def test_geom_side_ply_never_replaces_the_ground_truth_mesh(tmp_path):
    # `geom` writes OUT.ply beside OUT.h5: with -o room.h5 that is the --gt-mesh room.ply; refused before training
    mesh = panel_ply(tmp_path / "room.ply")
    before = mesh.read_bytes()
    r = invoke("--force", "geom", tmp_path / "calib.h5", "--gt-mesh", mesh, "-o", tmp_path / "room.h5")
    assert_refused(r, mesh, "input of this command")
    assert mesh.read_bytes() == before and not (tmp_path / "room.h5").exists()


def test_rf_fit_refuses_a_file_of_another_kind_before_it_fits(tmp_path):
    """rf-fit checks its output before the fit: a measurements artifact at -o is refused at once (exit 2), and
    its bytes are unchanged."""
    meas = tmp_path / "m.h5"
    write_artifact(meas, "measurements", {"tx_pos": np.zeros((1, 3)), "rx_pos": np.ones((1, 3)),
                                          "freq_hz": np.array([2.4e9]), "path_gain_db": np.full((1, 1), -50.0)},
                   attrs={"task": "rssi", "scene": "x"})
    other = tmp_path / "other.h5"
    other.write_bytes(meas.read_bytes())
    before = other.read_bytes()
    r = CliRunner().invoke(app, ["rf-fit", str(tmp_path / "missing_scene.h5"), str(meas), "-o", str(other)])
    assert r.exit_code == 2 and "refusing to replace it" in r.output and "measurements" in r.output, r.output
    assert other.read_bytes() == before
