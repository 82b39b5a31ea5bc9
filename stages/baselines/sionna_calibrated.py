"""Ray tracing with calibrated materials (baseline): Sionna RT on a mesh, one radio material per object
class, its relative permittivity and conductivity fitted to training links by gradient descent through
Sionna's differentiable path solver (Dr.Jit automatic differentiation). Command line:
scripts/baseline_sionna_calibrated.py.

What a radio engineer does first with a ray tracer and a few measurements:
- classes: a labelled mesh (`rfir simulate`'s meshes/<scene>_gt.ply, face labels, names in the
  labels.json beside it) gives one material per object class, named as the room model names them
  (`class_names`: desk_03 -> desk). A mesh without labels (e.g. `rfir geom`'s mesh from photos) gets
  one global material; the results say so.
- start: every class made of the guessed ITU material (`--material`, Sionna's ITU-R P.2040 values at
  the measurement frequency) as slabs `--thickness` m thick; the thickness stays at the guess unless
  `--learn-thickness` (then thickness = exp(w_c) m is calibrated too).
- parameters per class c: eps_r = 1 + exp(u_c) (Sionna needs eps_r >= 1), sigma = exp(v_c) S/m; Adam
  with a step size decaying geometrically by `--lr-decay` over the run.
- loss: mean |P_dB(predicted) - P_dB(measured)| over a fixed random subsample of about `--links`
  training links (every training link of a random set of receivers, `link_groups`), grouped by
  transmitter; each Adam step solves `--tx-per-step` transmitter groups (one Sionna
  solve each, in Dr.Jit's "evaluated" loop mode, which supports reverse-mode AD) and accumulates
  the gradient of every group.
- power per link as the simulator combines paths (rfir_stages.simulate.solve): specular and
  refracted paths summed coherently with their delay phase exp(-j 2 pi f tau), diffuse paths summed
  as power. The calibration solves use the prediction's bounces and rays by default (`--depth`,
  `--samples`; fewer bias the materials toward making up the missing paths); the gradient of Sionna's Monte-Carlo path search
  itself is not taken (paths are found, then their fields differentiated).
- prediction: every link of the file with the fitted materials and `rfir simulate`'s default physics
  (configs/simulate.toml, as the guessed-material ray-tracing baseline uses), scored on the split's
  test rows; the split rows are rfir's (`training_rows` of the RSSI fit: the file's split column, or 4
  transmitters held out with seed 0).
"""
from __future__ import annotations

import json
import math
import re
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, RfirError, StageError

GLOBAL_CLASS = "all"
SPLITS = ("random", "holdout_tx")


def _silent(message: str) -> None:
    """The default `say`: progress lines are the caller's to show (the script prints them)."""


@dataclass
class CalibSettings:
    """Calibration settings (units: m, S/m, dB)."""

    material: str = "concrete"    # guessed ITU material every class starts from
    thickness_m: float = 0.2      # slab thickness Sionna assumes at the start
    learn_thickness: bool = False  # calibrate each class's thickness too (else it stays at thickness_m)
    iterations: int = 40          # Adam steps
    lr: float = 0.1               # Adam step size on u = log(eps_r - 1) and v = log(sigma), first step
    lr_decay: float = 0.1         # last step's size / first step's (geometric in between)
    links: int = 400              # training links in the calibration subsample
    tx_per_step: int = 4          # transmitter groups solved per Adam step
    max_depth: int | None = None        # bounces of the calibration solves (None: the prediction's)
    samples_per_src: int | None = None  # rays per transmitter of the calibration solves (None: the prediction's)
    seed: int = 0


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------
def mesh_classes(mesh) -> tuple[np.ndarray, list[str], bool]:
    """(face_class [F] int, class names [C], labelled) of a geom.mesh_io.Mesh.

    Labelled: the class of a face is its label's name through `class_names` (labels without a name
    in labels.json are classes of their own, `label-N`). Without labels: one class, GLOBAL_CLASS."""
    from rfir_stages.model.fit_physical import label_class_names as class_names

    if mesh.labels is None:
        return np.zeros(len(mesh.faces), np.int64), [GLOBAL_CLASS], False
    ids = np.unique(mesh.labels)
    names = class_names([mesh.label_names.get(int(i), f"label-{int(i)}") for i in ids])
    classes = sorted(set(names))
    of_label = {int(i): classes.index(n) for i, n in zip(ids, names)}
    return np.array([of_label[int(v)] for v in mesh.labels], np.int64), classes, True


def class_spec(mesh, face_class: np.ndarray, classes: list[str], material: str, thickness_m: float):
    """A SceneSpec with one object per class (the faces of that class, vertices re-indexed)."""
    from rfir_stages.simulate.scenes import SceneObject, SceneSpec

    objects = []
    for c, name in enumerate(classes):
        faces = np.asarray(mesh.faces)[face_class == c]
        used, inv = np.unique(faces, return_inverse=True)
        objects.append(SceneObject(_object_id(name), c, np.asarray(mesh.vertices, np.float64)[used],
                                   inv.reshape(-1, 3).astype(np.int32), material, "plaster", (0.8, 0.8, 0.8),
                                   float(thickness_m)))
    v = np.asarray(mesh.vertices, np.float64)
    return SceneSpec("calibrated", "room", objects, np.stack([v.min(0), v.max(0)]))


def _object_id(name: str) -> str:
    """A class name as a Mitsuba shape id (letters, digits, _ and -)."""
    return "cls-" + re.sub(r"[^A-Za-z0-9_-]", "_", name)


def rssi_rows(meas, split: str, where: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(train rows, test rows, description) as rfir's RSSI fit and predict choose them."""
    from rfir_stages.rf_fit.rssi_split import rssi_settings, training_rows

    cfg = dict(rssi_settings({}), split="file" if split == "random" else "holdout_tx")
    if split == "holdout_tx" and meas.get("tx_id") is not None:
        n_tx = np.unique(np.asarray(meas["tx_id"])).size
        if not 0 < int(cfg["holdout_tx"]) < n_tx:
            raise StageError(f"split holdout_tx holds out {cfg['holdout_tx']} transmitters (as rfir does); the file "
                             f"has {n_tx}", path=where)
    train, held = training_rows(meas, cfg, 0, where)
    if split == "random":
        test = np.flatnonzero(np.asarray(meas["split"]) == 1)
        desc = "random split of the file (split column)"
    else:
        test = np.flatnonzero(np.isin(np.asarray(meas["tx_id"]), held))
        desc = f"transmitters {held.tolist()} held out"
    if test.size == 0:
        raise StageError(f"split {split!r} leaves no test link", path=where)
    return train, test, desc


def link_table(meas, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Distinct transmitter / receiver positions [T, 3], [R, 3] m and each row's (tx_id, rx_id)."""
    for key in ("tx_pos", "rx_pos", "tx_id", "rx_id", "path_gain_db", "freq_hz"):
        if meas.get(key) is None:
            raise InputFileError(f"not RSSI measurements: no {key!r}", path=where)
    tx_id, rx_id = np.asarray(meas["tx_id"], np.int64), np.asarray(meas["rx_id"], np.int64)
    if tx_id.size == 0:
        raise InputFileError("the measurements hold no links", path=where)
    tx_all, rx_all = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
    tx = np.zeros((tx_id.max() + 1, 3))
    rx = np.zeros((rx_id.max() + 1, 3))
    tx[tx_id], rx[rx_id] = tx_all, rx_all
    return tx, rx, tx_id, rx_id


# --------------------------------------------------------------------------------------------
# materials
# --------------------------------------------------------------------------------------------
def itu_values(material: str, freq_hz: float) -> tuple[float, float]:
    """(eps_r, sigma S/m) of an ITU material at freq_hz, from Sionna's ITU-R P.2040 table."""
    import mitsuba as mi

    from rfir_stages.simulate.radio_scene import set_variant

    set_variant()
    from sionna.rt.radio_materials.itu import itu_material

    try:
        eps, sigma = itu_material(material, mi.Float(freq_hz))
    except Exception as exc:  # Sionna raises ValueError with its own wording for an unknown name
        raise ConfigError(f"--material {material!r}: not an ITU material Sionna knows ({exc})") from None
    return float(eps[0]), float(sigma[0])


class ClassMaterials:
    """One Sionna RadioMaterial per class, parametrised by theta [C, 3] = (u, v, w):
    eps_r = 1 + exp(u), sigma = exp(v) S/m, slab thickness = exp(w) m."""

    def __init__(self, scene, classes: list[str], thickness_m: float, effects):
        import sionna.rt as rt

        from rfir_stages.simulate.radio_scene import apply_material_effects

        self.classes = list(classes)
        self.mats = []
        for name in self.classes:
            mat = rt.RadioMaterial(f"calib-{_object_id(name)}", thickness=float(thickness_m),
                                   relative_permittivity=2.0, conductivity=0.01)
            scene.objects[_object_id(name)].radio_material = mat
            self.mats.append(mat)
        apply_material_effects(scene, effects)   # the simulator's scattering coefficient and pattern
        self._vars = None

    @staticmethod
    def to_theta(eps_r, sigma, thickness_m) -> np.ndarray:
        """theta [C, 3] of eps_r, sigma S/m, thickness m [C] each."""
        return np.stack([np.log(np.maximum(np.asarray(eps_r, np.float64) - 1.0, 1e-6)),
                         np.log(np.maximum(np.asarray(sigma, np.float64), 1e-9)),
                         np.log(np.maximum(np.asarray(thickness_m, np.float64), 1e-6))], -1)

    @staticmethod
    def values(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(eps_r [C], sigma [C] S/m, thickness [C] m) of theta [C, 3]."""
        theta = np.asarray(theta, np.float64)
        return 1.0 + np.exp(theta[:, 0]), np.exp(theta[:, 1]), np.exp(theta[:, 2])

    def set(self, theta: np.ndarray, grad: bool) -> None:
        """Put theta into the materials; with grad, as Dr.Jit variables whose gradients `grad_theta` reads."""
        import drjit as dr
        import mitsuba as mi

        self._vars = []
        for mat, row in zip(self.mats, np.asarray(theta, np.float64)):
            # opaque: a literal constant would be compiled into Dr.Jit's kernels, so every new value
            # would recompile them (seconds per solve)
            g = [mi.Float(float(x)) for x in row]
            dr.make_opaque(*g)
            if grad:
                dr.enable_grad(*g)
                self._vars.append(g)
            eps, sigma, thick = 1.0 + dr.exp(g[0]), dr.exp(g[1]), dr.exp(g[2])
            dr.make_opaque(eps, sigma, thick)
            mat.relative_permittivity, mat.conductivity, mat.thickness = eps, sigma, thick

    def grad_theta(self) -> np.ndarray:
        """d loss / d theta [C, 3] after dr.backward."""
        import drjit as dr

        return np.array([[float(dr.grad(x)[0]) for x in g] for g in self._vars])


# --------------------------------------------------------------------------------------------
# differentiable link power
# --------------------------------------------------------------------------------------------
def power_db_dr(paths, freq_hz: float, num_rx: int):
    """Dr.Jit TensorXf [R]: path gain in dB per receiver of a one-transmitter solve, combined as the
    simulator does (coherent specular/refracted sum + diffuse power), differentiable w.r.t. materials."""
    import drjit as dr
    import mitsuba as mi
    import sionna.rt as rt

    ar, ai = paths.a
    n_p = int(np.prod(dr.shape(ar))) // max(num_rx, 1)
    if n_p == 0:
        return mi.TensorXf(np.full(num_rx, -300.0, np.float32))
    ar = dr.reshape(mi.TensorXf, ar, (num_rx, n_p))
    ai = dr.reshape(mi.TensorXf, ai, (num_rx, n_p))
    tau = dr.reshape(mi.TensorXf, dr.detach(paths.tau), (num_rx, n_p))
    valid = np.asarray(paths.valid).reshape(num_rx, n_p).astype(bool)
    inter = np.asarray(paths.interactions).reshape(-1, num_rx, n_p)
    diffuse = (inter == int(rt.InteractionType.DIFFUSE)).any(0) & valid
    coherent, diffuse = mi.TensorXb(valid & ~diffuse), mi.TensorXb(diffuse)
    ph = (-2.0 * math.pi * float(freq_hz)) * tau
    c, s = dr.cos(ph), dr.sin(ph)
    zero = mi.TensorXf(np.zeros((num_rx, n_p), np.float32))
    # select, not multiply: invalid paths may hold NaN amplitudes
    hr = dr.sum(dr.select(coherent, ar * c - ai * s, zero), axis=1)
    hi = dr.sum(dr.select(coherent, ar * s + ai * c, zero), axis=1)
    pd = dr.sum(dr.select(diffuse, ar * ar + ai * ai, zero), axis=1)
    return (10.0 / math.log(10.0)) * dr.log(hr * hr + hi * hi + pd + 1e-30)


def link_groups(train: np.ndarray, tx_id: np.ndarray, rx_id: np.ndarray, links: int,
                seed: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The calibration subsample: (receiver ids [K], training rows per transmitter).

    K receivers drawn at random so that about `links` training links join them to the training
    transmitters; every training link between those receivers and any transmitter is in the
    subsample. Why receivers and not single links: the solver places every receiver once and only
    the transmitter moves between solves (a new set of receivers recompiles Dr.Jit's kernels), and
    a solve costs about the same for a few dozen receivers as for one."""
    rng = np.random.default_rng(seed)
    n_tx = np.unique(tx_id[train]).size
    rx_ids = np.unique(rx_id[train])
    k = min(rx_ids.size, max(1, math.ceil(int(links) / max(n_tx, 1))))
    chosen = np.sort(rng.choice(rx_ids, size=k, replace=False))
    pick = train[np.isin(rx_id[train], chosen)]
    return chosen, [pick[tx_id[pick] == t] for t in np.unique(tx_id[pick])]


def calibrate(scene, mats: ClassMaterials, tx, rx, tx_id, rx_id, y, subsample, freq_hz, s: CalibSettings,
              say=_silent) -> dict:
    """Adam on theta over the subsample (`link_groups`: receiver ids, rows per transmitter); returns
    theta, per-step batch losses and the subsample MAE before / after."""
    import drjit as dr
    import sionna.rt as rt

    from rfir_stages.simulate.radio_scene import set_devices

    solver = rt.PathSolver()
    solver.loop_mode = "evaluated"   # reverse-mode AD needs evaluated loops
    kw = dict(max_depth=int(s.max_depth), samples_per_src=int(s.samples_per_src),
              max_num_paths_per_src=max(20 * int(s.samples_per_src), 100000), synthetic_array=True, los=True,
              specular_reflection=True, diffuse_reflection=any(float(m.scattering_coefficient[0]) > 0
                                                                for m in mats.mats),
              refraction=True, diffraction=False, seed=7)
    eps0, sig0 = itu_values(s.material, freq_hz)
    n_c = len(mats.classes)
    theta = ClassMaterials.to_theta(np.full(n_c, eps0), np.full(n_c, sig0), np.full(n_c, s.thickness_m))
    learned = np.array([True, True, bool(s.learn_thickness)])    # Adam moves these columns of theta
    m1, m2 = np.zeros_like(theta), np.zeros_like(theta)
    b1, b2 = 0.9, 0.999
    rng = np.random.default_rng(s.seed)
    rx_sub, groups = subsample
    n_links = sum(len(g) for g in groups)
    set_devices(scene, tx[:1], rx[rx_sub])
    tx_dev = scene.transmitters["tx0"]

    def group_loss(g: np.ndarray, weight: float, grad: bool) -> float:
        """Solve the group's transmitter to every subsample receiver; weight x the summed |dB error| of its rows."""
        import mitsuba as mi

        tx_dev.position = [float(v) for v in tx[tx_id[g[0]]]]
        paths = solver(scene, **kw)
        pred = power_db_dr(paths, freq_hz, len(rx_sub))
        col = np.searchsorted(rx_sub, rx_id[g])
        used, target = np.zeros(len(rx_sub), bool), np.zeros(len(rx_sub), np.float32)
        used[col], target[col] = True, y[g]
        err = dr.select(mi.TensorXb(used), dr.abs(pred - mi.TensorXf(target)), mi.TensorXf(np.zeros(len(rx_sub),
                                                                                                     np.float32)))
        loss = dr.sum(err, axis=None) * weight
        if grad:
            dr.backward(loss)
        return float(np.asarray(loss).ravel()[0])

    def full_mae(th) -> float:
        mats.set(th, grad=False)
        return sum(group_loss(g, 1.0 / n_links, False) for g in groups)

    t0 = time.time()
    initial = full_mae(theta)
    say(f"calibrate: {len(mats.classes)} classes, {n_links} links ({len(rx_sub)} receivers x {len(groups)} "
        f"transmitters), depth {s.max_depth}, {s.samples_per_src} rays per transmitter, start "
        f"{s.material} (eps_r {eps0:.3g}, sigma {sig0:.3g} S/m), subsample MAE {initial:.3f} dB ({time.time() - t0:.0f} s)")
    losses = []
    order = []
    for it in range(int(s.iterations)):
        if len(order) < s.tx_per_step:
            order += list(rng.permutation(len(groups)))
        batch, order = order[:s.tx_per_step], order[s.tx_per_step:]
        mats.set(theta, grad=True)
        n_b = sum(len(groups[k]) for k in batch)
        loss = sum(group_loss(groups[k], 1.0 / n_b, True) for k in batch)
        g = mats.grad_theta() * learned
        if not np.all(np.isfinite(g)):
            raise StageError(f"calibration gradient not finite at step {it + 1}; lower --lr")
        m1 = b1 * m1 + (1 - b1) * g
        m2 = b2 * m2 + (1 - b2) * g * g
        lr = s.lr * s.lr_decay ** (it / max(int(s.iterations) - 1, 1))   # smaller steps settle the batch noise
        theta = theta - lr * (m1 / (1 - b1 ** (it + 1))) / (np.sqrt(m2 / (1 - b2 ** (it + 1))) + 1e-8)
        losses.append(loss)
        say(f"calibrate: step {it + 1}/{s.iterations}  batch MAE {loss:.3f} dB  ({time.time() - t0:.0f} s)")
    final = full_mae(theta)
    say(f"calibrate: subsample MAE {initial:.3f} -> {final:.3f} dB ({time.time() - t0:.0f} s)")
    return {"theta": theta, "losses": losses, "initial_subsample_mae_db": initial,
            "final_subsample_mae_db": final, "calibrate_s": time.time() - t0, "subsample_links": n_links,
            "start": {"material": s.material, "eps_r": eps0, "sigma_s_per_m": sig0}}


# --------------------------------------------------------------------------------------------
# the baseline
# --------------------------------------------------------------------------------------------
def run(mesh_path, meas_path, split: str, results_path, s: CalibSettings, say=_silent) -> dict:
    """Calibrate on the training rows, predict every link, score the test rows; writes results_path."""
    from rfir_core.artifacts import read_artifact
    from rfir_core.progress import NullProgress
    from rfir_stages.geom.mesh_io import read_ply_mesh
    from rfir_stages.simulate.radio_scene import load_radio_scene
    from rfir_stages.simulate.rssi import simulate_rssi
    from rfir_stages.simulate.settings import parse_settings

    t0 = time.time()
    if split not in SPLITS:
        raise ConfigError(f"--split {split!r}: expected one of {', '.join(SPLITS)}")
    if (s.iterations < 0 or s.links < 1 or s.tx_per_step < 1 or (s.max_depth or 1) < 1
            or (s.samples_per_src or 1) < 1):
        raise ConfigError("need --iterations >= 0, --links >= 1, --tx-per-step >= 1, --depth >= 1, --samples >= 1")
    if not s.thickness_m > 0:
        raise ConfigError("--thickness must be > 0 m")
    mesh = read_ply_mesh(mesh_path)
    meas = read_artifact(meas_path, "measurements")
    where = str(meas_path)
    tx, rx, tx_id, rx_id = link_table(meas, where)
    freqs = np.asarray(meas["freq_hz"], np.float64)
    itu_values(s.material, float(freqs[0]))          # an unknown material fails before any work
    train, test, split_desc = rssi_rows(meas, split, where)
    y = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    face_class, classes, labelled = mesh_classes(mesh)
    scope = (f"one material per object class ({len(classes)} classes from the mesh's labels)" if labelled
             else "one global material: the mesh has no object labels")
    say(f"sionna-calibrated: {scope}; {split_desc}; {train.size} training / {test.size} test links at "
        f"{freqs[0] / 1e9:g} GHz")

    settings = parse_settings(None)
    effects = settings.material_effects()
    physics = settings.physics_for("rssi")
    s = replace(s, max_depth=s.max_depth or physics.max_depth, samples_per_src=s.samples_per_src or physics.samples_per_src)
    spec = class_spec(mesh, face_class, classes, s.material, s.thickness_m)
    work = Path(results_path).with_suffix("")
    with tempfile.TemporaryDirectory(prefix="rfir-calibrated-") as tmp:   # the scene's XML + PLY, read at load
        scene = load_radio_scene(spec, Path(tmp), float(freqs[0]), effects)
    mats = ClassMaterials(scene, classes, s.thickness_m, effects)
    subsample = link_groups(train, tx_id, rx_id, s.links, s.seed)
    fit = calibrate(scene, mats, tx, rx, tx_id, rx_id, y, subsample, float(freqs[0]), s, say)

    mats.set(fit["theta"], grad=False)
    say(f"predict: {len(tx)} transmitters x {len(rx)} receivers, simulate's default physics (depth "
        f"{physics.max_depth}, {physics.samples_per_src} rays per transmitter)")
    t_pred = time.time()
    _, power, sim_tx, sim_rx, _, _ = simulate_rssi(scene, tx, rx, freqs[:1], physics, NullProgress(), "ray tracing")
    pred_s = time.time() - t_pred
    pred_all = 10 * np.log10(np.maximum(power[:, 0], 1e-25))          # no path: -250 dB
    pred = pred_all[tx_id * len(rx) + rx_id]                           # simulate_rssi's rows are Tx-major
    assert np.all(sim_tx[tx_id * len(rx) + rx_id] == tx_id) and np.all(sim_rx[tx_id * len(rx) + rx_id] == rx_id)
    eps, sigma, thick = ClassMaterials.values(fit["theta"])
    err = np.abs(pred - y)
    out = {
        "name": work.name, "task": "rssi",
        "method": "Sionna RT with per-class materials (eps_r, sigma) calibrated by gradient descent through its "
                  "differentiable path solver; rfir_stages.baselines.sionna_calibrated",
        "mesh": str(mesh_path), "mesh_triangles": int(len(mesh.faces)), "measurements": str(meas_path),
        "freq_hz": float(freqs[0]), "split": split, "materials_scope": scope,
        "metrics": {"split": split_desc, "num_train": int(train.size), "num_test": int(test.size),
                    "mae_db": float(err[test].mean()), "mae_train_db": float(err[train].mean()),
                    "rmse_db": float(np.sqrt(np.mean(err[test] ** 2))),
                    "links_without_path": int(np.sum(pred <= -240)),
                    "calibration_subsample_mae_before_db": fit["initial_subsample_mae_db"],
                    "calibration_subsample_mae_after_db": fit["final_subsample_mae_db"]},
        "materials": {c: {"eps_r": float(e), "sigma_s_per_m": float(g), "thickness_m": float(d)}
                      for c, e, g, d in zip(classes, eps, sigma, thick)},
        "start_material": fit["start"],
        "settings": {**asdict(s), "subsample_links": fit["subsample_links"],
                     "calibration_physics": "specular, refraction" + (", diffuse" if effects.scattering_coefficient
                                                                       > 0 else "") + f"; depth {s.max_depth}",
                     "prediction_physics": {"max_depth": physics.max_depth, "samples_per_src": physics.samples_per_src,
                                            "diffuse": physics.diffuse,
                                            "scattering_coefficient": effects.scattering_coefficient,
                                            "scattering_pattern": effects.scattering_pattern}},
        "fit": {"batch_mae_db": [float(v) for v in fit["losses"]]},
        "calibrate_s": fit["calibrate_s"], "predict_s": pred_s, "wall_time_s": time.time() - t0,
    }
    results_path = Path(results_path)
    results_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = results_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    tmp.replace(results_path)      # never a half-written results file
    return out
