"""calibrate.sfm.matcher = "auto": the sequence probe and its rule, loop-closure keyframes, the choice and the
exhaustive fallback (rfir_stages.calibrate.matcher_choice, sfm.run_sfm). The probe runs pycolmap on a synthetic
pan: crops stepping along one large textured image (a camera moving past a wall), named in order or not."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_stages.calibrate import matcher_choice as mc
from rfir_stages.calibrate.sfm import SfmOptions

PAN = (30, 50, 320, 240)        # photos, step [px], photo width and height [px]: neighbours share 270 of 320 px


def test_probe_pairs_are_neighbours_and_far_ones():
    near, far = mc.probe_pairs(120, 8, seed=3)
    assert len(near) == 8 and all(j == i + 1 for i, j in near)
    assert near[0][0] == 0 and near[-1][1] == 119                  # spread over the whole sequence
    assert len(far) >= 6
    for i, j in far:
        gap = min(j - i, 120 - (j - i))                              # round the loop
        assert 30 <= gap <= 60, (i, j)


@pytest.mark.parametrize("near, far, expected", [
    ([400, 380, 20, 350, 0, 410, 390, 300], [3, 0, 10, 5, 0, 1, 2, 8], True),     # 6 of 8 verify, far pairs poor
    ([400, 380, 10, 350, 0, 410, 390, 0], [3, 0, 10, 5, 0, 1, 2, 8], False),      # 5 of 8: neighbours do not overlap
    ([400, 380, 300, 350, 420, 410, 390, 300], [300, 250, 280, 260, 190, 310, 150, 200], False),   # far as good
    ([40, 40, 40, 40, 40, 40, 40, 40], [20, 20, 20, 20, 20, 20, 20, 20], True),   # exactly twice the far median
    ([39, 39, 39, 39, 39, 39, 39, 39], [20, 20, 20, 20, 20, 20, 20, 20], False),
])
def test_sequence_rule(near, far, expected):
    sequence, why = mc.is_sequence(mc.SequenceProbe(np.array(near, float), np.array(far, float)), 15, 2.0)
    assert sequence is expected and why.startswith("a sequence" if expected else "not a sequence")


def test_loop_pairs():
    """Keyframes every 10th photo and the last (13 of 120): 78 pairs less the 12 neighbouring keyframe pairs that
    sequential matching makes already (no two keyframes here are a power of two apart)."""
    pairs = mc.loop_pairs(120, 10, 15)
    assert len(pairs) == 66
    assert (0, 119) in pairs and (0, 10) not in pairs and (110, 119) not in pairs
    assert all(j - i > 15 and (j - i) & (j - i - 1) != 0 for i, j in pairs)
    assert mc.loop_pairs(120, 0, 15) == [] and (0, 64) not in mc.loop_pairs(129, 64, 15)


def _probe_returning(near_value, far_value, calls):
    def probe(near, far):
        calls.append((near, far))
        return mc.SequenceProbe(np.full(len(near), near_value, float), np.full(len(far), far_value, float))
    return probe


def test_choice():
    auto = SfmOptions()
    calls = []
    seq = mc.choose(auto, 120, ("exhaustive", auto.reduced_num_features), _probe_returning(400, 5, calls))
    assert (seq.matcher, seq.num_features, seq.probed) == ("sequential", auto.max_num_features, True)
    assert "a sequence" in seq.reason and len(calls) == 1
    unordered = mc.choose(auto, 120, ("exhaustive", auto.reduced_num_features), _probe_returning(5, 5, calls))
    assert (unordered.matcher, unordered.num_features, unordered.probed) == ("exhaustive", auto.reduced_num_features,
                                                                             False)
    assert "not a sequence" in unordered.reason
    calls.clear()
    small = mc.choose(auto, 60, ("exhaustive", auto.max_num_features), _probe_returning(400, 5, calls))
    assert small.matcher == "exhaustive" and not calls                      # up to 60 photos: no probe
    named = mc.choose(SfmOptions(matcher="sequential"), 500, ("sequential", 8192), _probe_returning(400, 5, calls))
    assert named.matcher == "sequential" and not named.probed and not calls


def test_fallback_matchers():
    auto = SfmOptions()
    f = mc.fallback(auto, 120, True, 80)
    assert (f.matcher, f.num_features) == ("exhaustive", auto.reduced_num_features) and "80 of 120" in f.reason
    assert mc.fallback(auto, 400, True, 100).matcher == "spatial"
    assert mc.fallback(auto, 400, False, 100).matcher == "exhaustive"


class _FakeModel:
    def __init__(self, registered):
        self.registered = registered

    def num_reg_images(self):
        return self.registered


class _Log:
    def __init__(self):
        self.lines = []

    def log(self, message):
        self.lines.append(message)

    def task(self, description, total=None):
        from rfir_core.progress import NullProgress

        return NullProgress().task(description, total)


@pytest.mark.parametrize("sequential_registers, expected", [(100, "exhaustive"), (110, "sequential")])
def test_run_sfm_falls_back_below_nine_tenths(monkeypatch, tmp_path, sequential_registers, expected):
    """auto chooses sequential (the probe says so); registering 100 of 120 (< 90 %) it matches again exhaustively,
    says so and keeps that model; 110 of 120 is enough."""
    from rfir_stages.calibrate import sfm
    from rfir_stages.calibrate.images import ImageSet

    runs = []

    def fake_sfm_with(choice, images, work_dir, options, progress, known_K, known_centres):
        runs.append(choice.matcher)
        return _FakeModel(sequential_registers if choice.matcher == "sequential" else 120), 1

    monkeypatch.setattr(sfm, "_sfm_with", fake_sfm_with)
    monkeypatch.setattr(sfm, "probe_inliers", lambda images, work, options, K, near, far: mc.SequenceProbe(
        np.full(len(near), 400.0), np.full(len(far), 5.0)))
    images = ImageSet(tmp_path, [f"view_{k:03d}.png" for k in range(120)], 640, 480)
    log = _Log()
    model, _, choice = sfm.run_sfm(images, tmp_path, SfmOptions(), log)
    assert choice.matcher == expected and runs == (["sequential", "exhaustive"] if expected == "exhaustive"
                                                   else ["sequential"])
    assert model.num_reg_images() == (120 if expected == "exhaustive" else sequential_registers)
    assert log.lines[0].startswith("matching: sequential (a sequence")
    if expected == "exhaustive":
        assert "registered 100 of 120" in log.lines[1]


@pytest.fixture(scope="module")
def pan(tmp_path_factory):
    """Folder of PAN[0] crops of one textured image, stepping PAN[1] px to the right, named in that order."""
    import cv2

    n, step, w, h = PAN
    rng = np.random.default_rng(0)
    width = (n - 1) * step + w
    texture = np.zeros((h, width))
    for sigma in (1.5, 4.0, 10.0):           # blobs of several sizes: SIFT finds features at every scale
        texture += cv2.GaussianBlur(rng.normal(size=(h, width)), (0, 0), sigma) * sigma
    texture = (255 * (texture - texture.min()) / np.ptp(texture)).astype(np.uint8)
    folder = tmp_path_factory.mktemp("pan")
    crops = [texture[:, k * step:k * step + w] for k in range(n)]
    return folder, crops


def _write_named(folder, crops, order):
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for name_index, crop_index in enumerate(order):
        cv2.imwrite(str(folder / f"view_{name_index:03d}.png"), crops[crop_index])
    from rfir_stages.calibrate.images import scan_images

    return scan_images(folder)


@pytest.mark.parametrize("stride, expected", [(1, True), (7, False)])
def test_probe_on_a_pan(pan, stride, expected):
    """Named in capture order the pan is a sequence; named every 7th crop (neighbours in name order 350 px apart:
    no overlap) it is not."""
    from rfir_stages.calibrate.sfm import probe_inliers

    root, crops = pan
    n = len(crops)
    images = _write_named(root / f"stride_{stride}", crops, [(k * stride) % n for k in range(n)])
    options = SfmOptions(num_threads=2)
    near, far = mc.probe_pairs(n, options.probe_pairs, seed=0)
    probe = probe_inliers(images, root / f"work_{stride}", options, None, near, far)
    sequence, why = mc.is_sequence(probe, options.probe_min_inliers, options.probe_near_far_ratio)
    assert sequence is expected, why
    if expected:
        assert probe.near.min() >= 100 and np.median(probe.far) < options.probe_min_inliers
