"""Rendered attribute maps: a plate seen head-on shows its attribute values, the background is blank."""
import numpy as np

from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.predict.attribute_maps import plot_attribute_maps, render_attribute_maps


def _plate(size=0.4, spacing=0.02):
    h = size / 2
    v = np.array([[0, -h, -h], [0, h, -h], [0, h, h], [0, -h, h]], float)
    return gaussians_from_mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), spacing)


def test_plate_shows_its_attributes_and_blank_background(tmp_path):
    f = _plate()
    g = len(f["gaussians/means"])
    left = f["gaussians/means"][:, 1] < 0
    attrs = {"|Gamma|": np.where(left, 0.2, 0.8), "angle(Gamma) [rad]": np.full(g, 3.0), "R": np.full(g, 5.0)}
    maps = render_attribute_maps(f["gaussians/means"], f["gaussians/log_scales"], f["gaussians/rotations"],
                                 np.full(g, 0.9), attrs, np.array([2.0, 0, 0]), np.zeros(3), fov_deg=20,
                                 width=60, height=60)
    gam, ang, r = maps["|Gamma|"], maps["angle(Gamma) [rad]"], maps["R"]
    assert np.isnan(gam[0, 0]) and np.isnan(gam[30, 2])            # beyond the 0.4 m plate (fov 0.7 m)
    centre = slice(25, 35)
    np.testing.assert_allclose(r[centre, centre], 5.0, atol=1e-9)
    np.testing.assert_allclose(ang[centre, centre], 3.0, atol=1e-9)   # phasor average keeps the angle
    # image right = forward x up = +y seen from +x: the plate's y < 0 half is on the left
    assert np.nanmean(gam[20:40, 15:27]) < 0.3 and np.nanmean(gam[20:40, 33:45]) > 0.7
    assert plot_attribute_maps(tmp_path / "maps.png", maps, "plate").stat().st_size > 1000
