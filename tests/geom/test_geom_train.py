"""Training of `rfir geom` on a synthetic textured plane: it converges to the plane and its normal,
densification grows and prunes, losses switch off, and a resumed run equals an uninterrupted one."""
import numpy as np
import pytest
import torch

from rfir_core.artifacts import read_artifact
from rfir_stages.geom.data import background_colour, load_views
from rfir_stages.geom.densify import DensifyStats, densify_and_prune
from rfir_stages.geom.init import init_from_points
from rfir_stages.geom.model import GaussianModel, logit
from rfir_stages.geom.stage import run
from rfir_stages.geom.train import TrainConfig, Trainer


def test_plane_converges_to_the_plane_and_its_normal(plane_capture, small_config, tmp_path):
    calib, mesh = plane_capture
    cfg = small_config(evaluate={"gt_mesh": str(mesh)})
    result = run(calib, tmp_path / "scene.h5", cfg)
    art = read_artifact(tmp_path / "scene.h5", "scene")
    opaque = art["gaussians/opacities"] > 0.5
    assert opaque.sum() > 100
    z = art["gaussians/means"][opaque, 2]
    nz = art["gaussians/normals"][opaque, 2]
    assert np.abs(z).mean() < 0.005  # on the plane (sparse points were 2 mm off it)
    assert np.mean(nz > 0) > 0.97  # oriented towards the cameras (all above the plane)
    assert np.degrees(np.arccos(np.clip(np.median(np.abs(nz)), 0, 1))) < 8.0
    m = result.metrics
    assert m["psnr_db"] > 20.0
    assert m["normal_error_deg_median"] < 8.0
    assert m["depth_error_m_median"] < 0.005
    loss = art.free["training"]["loss"]
    assert loss[-10:].mean() < 0.6 * loss[:10].mean()


def _setup(capture, tiny_config, **over):
    calib_path, _ = capture
    calib = read_artifact(calib_path, "calib")
    table = tiny_config(**over)
    views = load_views(calib, calib_path, 48, 3)
    init = init_from_points(calib["points_xyz"], calib["points_rgb"], np.stack([v.centre for v in views]),
                            max_points=300, init_opacity=0.3, thickness_ratio=0.3)
    cfg = TrainConfig.from_table(table, seed=3)
    model = GaussianModel(init.params, {})
    return Trainer(model, views, background_colour(views), cfg, extent_m=init.extent_m, ref_distance_m=0.7)


class _StopAt:
    """A progress reporter whose bar raises KeyboardInterrupt after `n` advances (a killed run)."""

    def __init__(self, n):
        self.n, self.seen = n, 0

    def log(self, message):
        pass

    def task(self, description, total=None):
        outer = self

        class _Bar:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                return False

            def advance(self, amount=1):
                outer.seen += amount
                if outer.seen > outer.n:
                    raise KeyboardInterrupt

            def update(self, **kw):
                pass

        return _Bar()


def test_resume_from_checkpoint_equals_uninterrupted_run(plane_capture, small_config, tmp_path):
    over = {"iterations": 40, "checkpoint_every": 10, "densify": {"every": 15, "from": 15, "until": 0.9}}
    full = _setup(plane_capture, small_config, **over)
    full.run()
    ckpt = tmp_path / "run.ckpt.pt"
    first = _setup(plane_capture, small_config, **over)
    with pytest.raises(KeyboardInterrupt):
        first.run(_StopAt(20), checkpoint=ckpt, key="k")  # killed after step 21, checkpoint at 20
    assert ckpt.exists()
    second = _setup(plane_capture, small_config, **over)
    result = second.run(checkpoint=ckpt, resume=True, key="k")
    assert result.resumed_at == 20
    assert second.model.num == full.model.num
    for name, value in full.model.params.items():
        torch.testing.assert_close(second.model.params[name], value, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(result.loss_curve, np.asarray(full.curve), rtol=1e-4)
    assert [d["total"] for d in result.densify_log] == [d["total"] for d in full.densify_log]
    with pytest.raises(Exception, match="other inputs or settings"):
        _setup(plane_capture, small_config, **over).run(checkpoint=ckpt, resume=True, key="different")


def test_each_loss_switches_off(plane_capture, small_config):
    weights = {"l1": 0.8, "ssim": 0.0, "normal": 0.0, "depth_uncertainty": 0.0, "normal_smooth": 0.0}
    tr = _setup(plane_capture, small_config, loss=weights)
    _, parts = tr.loss(0, geometry=True)
    assert set(parts) == {"l1"}
    tr = _setup(plane_capture, small_config)
    _, parts = tr.loss(0, geometry=True)
    assert set(parts) == {"l1", "ssim", "normal", "depth_uncertainty", "normal_smooth"}
    _, parts = tr.loss(0, geometry=False)  # before geometry_from only the photometric terms
    assert set(parts) == {"l1", "ssim"}


def test_densify_splits_large_clones_small_and_prunes_transparent():
    n = 4
    params = {"means": torch.zeros(n, 3), "log_scales": torch.log(torch.tensor([[0.05] * 3, [0.001] * 3, [0.001] * 3,
                                                                                 [0.001] * 3])),
              "rotations": torch.tensor([[1.0, 0, 0, 0]] * n), "opacity_logits": logit(torch.tensor([0.9, 0.9, 0.9, 0.001])),
              "color_logits": torch.zeros(n, 3), "normals_raw": torch.tensor([[0, 0, 1.0]] * n)}
    model = GaussianModel(params, {"means": 0.1})
    stats = DensifyStats.zeros(n)
    stats.add(torch.tensor([[1.0, 0, 0], [1.0, 0, 0], [0.001, 0, 0], [0.0, 0, 0]]))
    rep = densify_and_prune(model, stats, grow_fraction=0.67, max_gaussians=100, split_scale=0.01, min_opacity=0.01,
                            max_scale=1.0, generator=torch.Generator().manual_seed(0))
    assert (rep.split, rep.cloned, rep.pruned) == (1, 1, 1)
    # kept: the small grown one and the untouched one; new: 1 clone + 2 halves of the split one
    assert model.num == 2 + 1 + 2 == rep.total
    scales = torch.exp(model.params["log_scales"]).max(-1).values
    assert torch.isclose(scales, torch.tensor(0.05 / 1.6)).sum() == 2
    assert model.exp_avg["means"].shape == (5, 3)
