"""Bad inputs to rfir calibrate: each gets one clear error, and nothing is written."""
import csv

import cv2
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rfir_cli.commands import calibrate as calibrate_command
from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_stages.calibrate import CalibrateInputs, run


def _images(folder, n, size=(320, 240), seed=0):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"img_{i:02d}.png"), rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    return folder


def _fails(tmp_path, error, match, **kw):
    out = tmp_path / "out" / "calib.h5"
    kw.setdefault("no_metric", True)
    with pytest.raises(error, match=match):
        run(CalibrateInputs(out=out, **kw))
    assert not out.exists() and not (tmp_path / "out" / "calib.png").exists()
    assert not (tmp_path / "out" / "calib_colmap").exists()


def test_missing_and_empty_folder(tmp_path):
    _fails(tmp_path, InputFileError, "not found", images=tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    _fails(tmp_path, InputFileError, "no images", images=tmp_path / "empty")


def test_too_few_images(tmp_path):
    _fails(tmp_path, InputFileError, r"only 2 image\(s\)", images=_images(tmp_path / "two", 2))


def test_unreadable_image(tmp_path):
    folder = _images(tmp_path / "imgs", 4)
    (folder / "broken.png").write_bytes(b"not a png at all")
    _fails(tmp_path, InputFileError, r"1 image\(s\) cannot be read.*broken.png", images=folder)


def test_mixed_sizes(tmp_path):
    folder = _images(tmp_path / "imgs", 4)
    _images(folder, 1, size=(200, 100), seed=1)  # overwrites img_00 with a different size
    _fails(tmp_path, InputFileError, "mixed sizes.*img_00.png \\(200x100\\)", images=folder)


def test_bad_settings_are_refused_before_any_work(tmp_path):
    from rfir_stages.calibrate import CalibrateOptions

    options = CalibrateOptions.from_config({"sfm": {"matcher": "bogus"}})
    with pytest.raises(ConfigError, match="matcher"):
        run(CalibrateInputs(tmp_path / "imgs", tmp_path / "c.h5", no_metric=True), options)


def test_spatial_matching_needs_every_centre(tmp_path):
    from rfir_stages.calibrate import CalibrateOptions

    images = _images(tmp_path / "imgs", 4)
    centres = tmp_path / "centres.csv"
    centres.write_text("".join(f"img_{i:02d}.png,{i},0,0\n" for i in range(3)))  # img_03 has none
    options = CalibrateOptions.from_config({"sfm": {"matcher": "spatial"}})
    for kw in ({"no_metric": True}, {"poses": centres}):
        with pytest.raises(ConfigError, match="spatial"):
            run(CalibrateInputs(images, tmp_path / "c.h5", **kw), options)
        assert not (tmp_path / "c.h5").exists()


def test_no_metric_reference_is_refused_before_any_work(tmp_path):
    _fails(tmp_path, ConfigError, "no metric reference.*--no-metric", images=tmp_path / "whatever", no_metric=False)


def test_references_that_name_missing_images(tmp_path):
    folder = _images(tmp_path / "imgs", 4)
    refs = tmp_path / "centres.csv"
    with open(refs, "w", newline="") as handle:
        csv.writer(handle).writerows([["a.png", 0, 0, 0], ["b.png", 1, 0, 0], ["img_00.png", 0, 1, 0]])
    _fails(tmp_path, InputFileError, "2 of 3 references name images that are not in", images=folder, poses=refs,
           no_metric=False)
    refs.write_text("img_00.png,0,0\n")
    _fails(tmp_path, InputFileError, "line 1: expected name,x,y,z", images=folder, poses=refs, no_metric=False)


def test_photos_that_do_not_overlap(tmp_path):
    """Unrelated noise images: SfM cannot register them; the error says how many and what to try."""
    folder = _images(tmp_path / "noise", 5)
    _fails(tmp_path, StageError, r"registered 0 of 5 images.*try: photos with more overlap", images=folder)


def test_colmap_model_folder_problems(tmp_path):
    folder = _images(tmp_path / "imgs", 4)
    _fails(tmp_path, InputFileError, "COLMAP model folder not found", images=folder, colmap_model=tmp_path / "none")
    (tmp_path / "model").mkdir()
    _fails(tmp_path, InputFileError, "no COLMAP model here", images=folder, colmap_model=tmp_path / "model")


def _app():
    app = typer.Typer()
    calibrate_command.register(app)

    @app.callback()
    def _root():  # a group, so the command is invoked by name as in the real CLI
        pass

    return app


def test_cli_reports_one_line_and_exit_code(tmp_path):
    result = CliRunner().invoke(_app(), ["calibrate", str(tmp_path / "nope"), "-o", str(tmp_path / "c.h5")])
    assert result.exit_code == 4  # ConfigError: no metric reference
    assert "no metric reference" in result.output
    result = CliRunner().invoke(_app(), ["calibrate", str(tmp_path / "nope"), "-o", str(tmp_path / "c.h5"),
                                         "--no-metric"])
    assert result.exit_code == 2 and "image folder not found" in result.output
    assert "Traceback" not in result.output


def test_cli_summary(sfm_run, object_views, tmp_path):
    out = tmp_path / "cli.h5"
    result = CliRunner().invoke(_app(), ["calibrate", str(object_views / "images"), "-o", str(out),
                                         "--colmap-model", str(sfm_run.model_dir),
                                         "--poses", str(object_views / "cameras.h5")])
    assert result.exit_code == 0, result.output
    for text in ("registered images", "mean reprojection error", "alignment error", "wrote"):
        assert text in result.output
    assert out.exists() and out.with_suffix(".png").exists()
