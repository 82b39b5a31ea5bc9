"""Fitting physical materials to measured path gains (the model of rfir_stages.model.physical).

Loss: mean squared dB error (or Huber in dB) between predicted and measured path gain. Predicted
power enters the logarithm with a floor 30 dB below the weakest measurement, so a surfel set that
predicts nothing (a plate seen edge-on) gives a large but finite loss, never -300 dB.

The loss over eps_r, sigma and thickness has several minima (a thin slab's reflection oscillates
with thickness; metal and a dense dielectric can look alike at one angle), so the fit starts from a
few physical materials (`STARTS`), runs each a short while with every material at that start, and
continues from the best (or from each of the `starts_kept` best, the lowest final loss kept); then each
material alone may switch to another start when that lowers the loss (a metal object beside wooden
ones), with a short refit after each round of switches. With several starts kept, the winner's materials
are then crossed with the others' one material at a time (`_cross_finals`: a swap is kept where it lowers
the loss) and fitted on for half the iterations. The state with the lowest training loss is kept (not the
last step).

Device gains (device_gains.py) are profiled out with the mean squared dB loss (`profile_gains`, variable projection):
they enter the dB prediction additively, so for any materials their optimum under the prior is closed form
(DeviceGains.profile: per device the shrunk weighted mean of its links' residuals), set before every evaluation
of the loss. The loss is then a function of the materials alone, and its gradient with the gains held at their
optimum is that function's gradient (the gains' own gradient is zero there). Adam moves only the materials; the
cost of a step does not grow with the number of gains, every evaluation (a start switch, a crossing) compares
materials at their best gains, and a gain seen by a few links is at its optimum from the first step, not after
hundreds of steps of 0.2 dB. The Huber loss has no closed form: there the gains are fitted by Adam beside the
materials (as with profile_gains off).
"""
from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from rfir_core.physics.materials import METAL_SIGMA_S_PER_M
from rfir_core.progress import NullProgress
from rfir_core.text import plural
from rfir_core.threads import single_thread_torch

from .device_gains import DeviceGains
from .identifiability import normal_reflection_ranges
from .physical import AggregatedPairs, MaterialParams
from .residual import SE_MARGIN

# (name, eps_r, sigma at 1 GHz [S/m], S, thickness [m]): a thin dielectric, a metal, a thick dense one. The metal
# start is a decade below the metal's conductivity, where the fitted range (physical.LOG10_SIGMA) ends: there the
# sigmoid of the parametrisation still passes a gradient, and its |Gamma| is a metal's to 0.01 dB.
METAL_START_SIGMA_1GHZ = METAL_SIGMA_S_PER_M / 10.0
STARTS = (("thin dielectric", 3.0, 0.01, 0.1, 0.01), ("metal", 1.5, METAL_START_SIGMA_1GHZ, 0.1, 0.01),
          ("thick dielectric", 6.0, 0.05, 0.1, 0.2))
# the start of a fit that continues from given materials (fit_materials' initial)
CONTINUED = ("continued", 3.0, 0.01, 0.1, 0.01)
FLOOR_BELOW_DB = 30.0
SWITCH_ROUNDS = 2


def _raw(params: MaterialParams) -> tuple:
    """The unconstrained tensors [N] of every property of one material (what the optimiser moves; a shared S
    is no one material's)."""
    if params.shared_scattering:
        return params.t_eps, params.t_sig, params.t_th
    return params.t_eps, params.t_sig, params.t_s, params.t_th


def _cross_finals(params: MaterialParams, others: list[MaterialParams], loss_now) -> int:
    """Greedy, one material at a time: that material's values from each of the other fits (`others`, fitted from
    other starts to their end) in place of its own; keep every swap that lowers the loss. A class that one start
    left in a poor basin (a thin lossy slab for 20 cm of concrete) may sit in a better one in another start's
    fit. Returns how many materials changed."""
    changed = 0
    with torch.no_grad():
        best = loss_now()
        for i in range(params.num):
            took = False
            for other in others:
                keep = [t[i].clone() for t in _raw(params)]
                for t, u in zip(_raw(params), _raw(other)):
                    t[i] = u[i]
                trial = loss_now()
                if trial < best - 1e-9:
                    best, took = trial, True
                else:
                    for t, v in zip(_raw(params), keep):
                        t[i] = v
            changed += took
    return changed


def _switch_starts(params: MaterialParams, loss_now) -> bool:
    """Greedy: for each material, the start (of STARTS) that lowers the loss most when that material
    alone is reset to it; keep every switch that helps. Returns whether any material switched."""
    switched = False
    with torch.no_grad():
        best = loss_now()
        for i in range(params.num):
            keep = [p[i].clone() for p in _raw(params)]
            choice = None
            for start in STARTS:
                _, eps, sig, s, th = start
                s = None if params.shared_scattering else s     # a shared S is no one material's
                params.set_values(i, eps_r=eps, sigma_1ghz=sig, scattering=s, thickness_m=th)
                trial = loss_now()
                if trial < best - 1e-9:
                    best, choice = trial, start
            for p, v in zip(_raw(params), keep):
                p[i] = v
            if choice is not None:
                _, eps, sig, s, th = choice
                s = None if params.shared_scattering else s
                params.set_values(i, eps_r=eps, sigma_1ghz=sig, scattering=s, thickness_m=th)
                switched = True
    return switched


@dataclass
class PhysicalFitConfig:
    """[rf_fit.physical] settings (configs/rf_fit.toml documents each)."""

    iterations: int = 200
    start_iterations: int = 40
    lr: float = 0.05
    loss: str = "db_mse"
    huber_db: float = 1.0
    fit_gain: bool = False
    half_space: bool = False
    sigma_exponent: float = 1.0
    reflection_ranges: bool = True
    # the starts carried through the start switching and the full fit, best after start_iterations first; the
    # lowest final training loss wins (a start that leads after a few steps need not lead at the end), and with
    # more than one, each material may take its value from another start's fit where that lowers the loss
    starts_kept: int = 1
    # one scattering coefficient S for every material (MaterialParams.shared_scattering; rf_fit.room.scattering)
    shared_scattering: bool = False
    # device gains at their closed-form optimum at every step (module docstring) rather than fitted by Adam
    profile_gains: bool = True


@dataclass
class PhysicalFitResult:
    params: MaterialParams
    train_mae_db: float
    initial_mae_db: float
    loss_curve: np.ndarray
    start: str
    wall_time_s: float
    extra: dict = field(default_factory=dict)
    steps: int = 0   # Adam steps run in all: every start's, the switch rounds', the fit's (more than cfg.iterations)


def predict_db(agg: AggregatedPairs, params: MaterialParams, floor_power: float = 0.0) -> torch.Tensor:
    """Predicted path gain [M, K] dB (power + floor_power in the logarithm)."""
    return 10 * torch.log10(agg.power(params.values(), params.gain_db) + floor_power)


def _loss(pred_db, target, cfg: PhysicalFitConfig, weights: torch.Tensor | None = None):
    """The fit's loss; weights [M, 1] (mean 1) weight each link's error (link_weights), None: all alike."""
    if cfg.loss == "db_huber":
        per = torch.nn.functional.smooth_l1_loss(pred_db, target, beta=cfg.huber_db, reduction="none")
    else:
        per = (pred_db - target) ** 2
    return per.mean() if weights is None else (per * weights).mean()


MODEL_ERROR_DB = 2.0   # the model's own error per link, beside a measurement's: what no averaging removes


def link_weights(sample_count: np.ndarray | None, sample_std_db: np.ndarray | None) -> np.ndarray | None:
    """Weights [M, 1] (mean 1) of links whose measured dB is the mean of sample_count [M] samples of spread
    sample_std_db [M] or [M, K] dB: the inverse of the link's error variance, MODEL_ERROR_DB^2 + std^2 / n, so
    that a link averaged from many samples counts more than a single noisy one, and no link counts more than
    the model's own error allows. None when the file records no sample counts."""
    if sample_count is None:
        return None
    n = np.maximum(np.asarray(sample_count, np.float64).reshape(-1), 1.0)
    std = np.zeros_like(n) if sample_std_db is None else np.asarray(sample_std_db, np.float64).reshape(len(n), -1)
    std = np.nan_to_num(np.mean(std, axis=1) if std.ndim == 2 else std, nan=0.0)
    w = 1.0 / (MODEL_ERROR_DB ** 2 + std ** 2 / n)
    return (w / w.mean())[:, None]


def fit_materials(agg: AggregatedPairs, num_materials: int, target_db: np.ndarray, cfg: PhysicalFitConfig,
                  progress=None, label: str = "physical", priors: dict | None = None,
                  devices: DeviceGains | None = None, initial: MaterialParams | None = None,
                  weights: np.ndarray | None = None) -> PhysicalFitResult:
    """Fit `num_materials` materials (the N of `agg`, or any model with the same `power`) so that the
    predicted path gain [M, K] dB matches target_db. priors: {material index: (eps_r, sigma at 1 GHz,
    thickness m)}, each such material's value at every start (a name that says "glass"). devices:
    per-device gains fitted beside the materials under their prior (device_gains.py), reset at each start;
    the fitted values are left in `devices`. initial: materials to continue from (a fit of a simpler model
    of the same links) instead of the starts; the devices then continue from their values too. weights [M, 1]:
    each link's weight in the loss (link_weights), None: all alike."""
    with single_thread_torch():   # a step is many small tensor ops: thread hand-offs cost more than they save
        return _fit_materials(agg, num_materials, target_db, cfg, progress, label, priors, devices, initial,
                              weights)


def _floor_power(target_db) -> float:
    """The fit's power floor [W]: FLOOR_BELOW_DB under the weakest measurement of target_db [M, K] dB."""
    return float(10 ** ((float(torch.as_tensor(target_db).min()) - FLOOR_BELOW_DB) / 10))


def training_predictor(agg: AggregatedPairs, target_db, devices: DeviceGains | None = None):
    """params -> predicted path gain [M, K] dB of the training links as the fit sees it: the power floor
    FLOOR_BELOW_DB under the weakest measurement (target_db [M, K] dB) and the device gains, if any."""
    floor = _floor_power(target_db)

    def pred(params: MaterialParams) -> torch.Tensor:
        out = predict_db(agg, params, floor)
        return out if devices is None else out + devices.link_db()
    return pred


def gains_from_all_links(devices: DeviceGains, params: MaterialParams, fit_links, fit_rows: np.ndarray, links_of,
                         target_db: np.ndarray, weights: np.ndarray | None = None, chunk_links: int = 512
                         ) -> np.ndarray:
    """Every device's gain from all its links (DeviceGains.fit_all) for the fitted materials `params`; returns the
    physical prediction [M] dB of every link (without the gains) they were taken from. The links the fit evaluated
    (fit_links, rows fit_rows [R] of the M training links) are predicted as traced, the others traced chunk_links
    at a time (links_of(rows) -> their links; as many as predict rssi traces at once) and dropped, so memory stays
    that of one chunk. target_db [M] or [M, 1] dB; weights [M] or [M, 1] (link_weights; None: all alike). The
    power floor is the fit's (FLOOR_BELOW_DB under the weakest fitted measurement)."""
    target = np.asarray(target_db, np.float64).reshape(-1)
    floor = _floor_power(target[fit_rows])
    pred = np.empty(len(target))
    rest = np.setdiff1d(np.arange(len(target)), fit_rows)
    with torch.no_grad(), single_thread_torch():
        pred[fit_rows] = predict_db(fit_links, params, floor)[:, 0].numpy()
        for lo in range(0, len(rest), chunk_links):
            rows = rest[lo:lo + chunk_links]
            pred[rows] = predict_db(links_of(rows), params, floor)[:, 0].numpy()
    devices.fit_all(torch.as_tensor(target - pred), None if weights is None else
                    torch.as_tensor(np.asarray(weights, np.float64).reshape(-1)))
    return pred


def reflection_ranges(agg: AggregatedPairs, params: MaterialParams, target_db: np.ndarray, freq_hz: float,
                      devices: DeviceGains | None = None, progress=None) -> np.ndarray:
    """[N, 2] range of |Gamma| at normal incidence at freq_hz [Hz] (the first fitted frequency) of each
    fitted material that the training links (target_db [M, K] dB) cannot tell apart from the fitted one
    (rfir_stages.model.identifiability; one standard error, the residual's SE_MARGIN)."""
    # incoherent room links have no local form (RoomLinks.material_part): every link is evaluated at each point
    local = (_material_predictor(agg, target_db, devices)
             if hasattr(agg, "material_split") and not getattr(agg, "incoherent", False) else None)
    return normal_reflection_ranges(training_predictor(agg, target_db, devices), params, target_db,
                                    float(freq_hz), margin=SE_MARGIN, progress=progress, local=local)


def _material_predictor(links, target_db, devices: DeviceGains | None):
    """identifiability.LocalPredictor of room links (RoomLinks.material_part: the part of the links that does
    not involve material i is evaluated once at the passed, fitted, materials); the same floor and device
    gains as training_predictor."""
    floor = _floor_power(target_db)

    def local(params: MaterialParams, i: int):
        part = links.material_part(i, params.values())
        gains = None if devices is None else devices.link_db()[part.rows]

        def pred(p: MaterialParams) -> torch.Tensor:   # [M_i, 1] dB
            out = 10 * torch.log10(part.power(p.values(), p.gain_db) + floor)[:, None]
            return out if gains is None else out + gains
        return part.rows, pred
    return local


def _fit_materials(agg, num_materials: int, target_db: np.ndarray, cfg: PhysicalFitConfig, progress, label: str,
                   priors: dict | None, devices: DeviceGains | None,
                   initial: MaterialParams | None = None, weights: np.ndarray | None = None) -> PhysicalFitResult:
    progress = progress or NullProgress()
    t0 = time.time()
    target = torch.as_tensor(np.asarray(target_db, dtype=np.float64))
    weight = None if weights is None else torch.as_tensor(np.asarray(weights, np.float64)).reshape(-1, 1)
    pred = training_predictor(agg, target, devices)
    profiled = devices is not None and cfg.profile_gains and cfg.loss == "db_mse"
    floor = _floor_power(target)

    def objective(params: MaterialParams) -> torch.Tensor:
        if profiled:
            physical = predict_db(agg, params, floor)
            devices.profile((target - physical.detach())[:, 0], None if weight is None else weight[:, 0])
            p = physical + devices.link_db().detach()
        else:
            p = pred(params)
        loss = _loss(p, target, cfg, weight)
        if devices is not None:
            loss = loss + devices.penalty(((p - target) ** 2).mean().detach(), len(target))
        return loss

    def snapshot(params: MaterialParams) -> dict:
        state = {k: v.detach().clone() for k, v in params.state_dict().items()}
        if devices is not None:
            state.update({f"devices.{k}": v.detach().clone() for k, v in devices.state_dict().items()})
        return state

    def restore(params: MaterialParams, state: dict) -> None:
        params.load_state_dict({k: v for k, v in state.items() if not k.startswith("devices.")})
        if devices is not None:
            devices.load_state_dict({k[len("devices."):]: v for k, v in state.items() if k.startswith("devices.")})

    def new(start) -> MaterialParams:
        _, eps, sig, s, th = start
        params = MaterialParams(num_materials, eps_r=eps, sigma_1ghz=sig, scattering=s,
                                thickness_m=None if cfg.half_space else th, sigma_exponent=cfg.sigma_exponent,
                                shared_scattering=cfg.shared_scattering)
        for i, (p_eps, p_sig, p_th) in (priors or {}).items():
            params.set_values(i, eps_r=p_eps, sigma_1ghz=p_sig, thickness_m=p_th)
        if devices is not None:
            with torch.no_grad():
                for g in devices.gains.values():
                    g.zero_()
        return params

    def run(params: MaterialParams, steps: int, bar) -> tuple[float, dict, list]:
        groups = [{"params": [params.t_eps, params.t_sig, params.t_s] + ([] if params.half_space else [params.t_th]),
                   "lr": cfg.lr}]
        if cfg.fit_gain:
            groups.append({"params": [params.gain_db], "lr": 0.2})
        if devices is not None and not profiled:
            groups.append({"params": list(devices.gains.values()), "lr": 0.2})
        opt = torch.optim.Adam(groups)
        best, best_state, curve = math.inf, None, []
        steps_run[0] += steps
        for _ in range(steps):
            opt.zero_grad()
            loss = objective(params)
            if float(loss.detach()) < best:
                best, best_state = float(loss.detach()), snapshot(params)
            loss.backward()
            opt.step()
            curve.append(float(loss.detach()))
            bar.update(loss=curve[-1])   # shown beside the bar, and in the plain lines of a log
            bar.advance(1)
        with torch.no_grad():
            final = float(objective(params))
        if final < best:
            best, best_state = final, snapshot(params)
        return best, best_state, curve

    steps_run = [0]
    starts = () if initial is not None else STARTS
    kept = 1 if initial is not None else max(1, min(int(cfg.starts_kept), len(STARTS)))
    num_data = int(torch.isfinite(target).sum())
    unknowns = _num_unknowns(num_materials, cfg, devices)
    if num_data < unknowns and initial is None:    # (a fit continued from another was told already)
        values = plural(len(target), "training link") + ("" if target.ndim < 2 or target.shape[1] == 1 else
                                                         f" x {plural(target.shape[1], 'frequency')}")
        progress.log(f"warning: {label}: {values} for {unknowns} unknowns "
                     f"({_unknowns_words(num_materials, cfg, devices)}): the links cannot determine them all "
                     "(many fits match them alike); measure more links or fit fewer materials")
    cross_steps = cfg.iterations // 2 if kept > 1 else 0     # the fit on after materials crossed between starts
    total = (len(starts) * cfg.start_iterations + kept * (SWITCH_ROUNDS * cfg.start_iterations + cfg.iterations)
             + cross_steps)
    with progress.task(f"rf-fit ({label})", total=total) as bar:
        tried = []
        for start in starts:
            params = new(start)
            loss, state, curve = run(params, cfg.start_iterations, bar)
            tried.append((loss, start, state, curve))
        if initial is not None:
            params = new(CONTINUED)
            state = {k: v.detach().clone() for k, v in initial.state_dict().items()}
            if devices is not None:   # the devices go on from where the fit of the simpler model left them
                state.update({f"devices.{k}": v.detach().clone() for k, v in devices.state_dict().items()})
            restore(params, state)
            tried.append((float(objective(params).detach()), CONTINUED, state, []))
        finals = []
        for _, start, state, curve0 in sorted(tried, key=lambda t: t[0])[:kept]:
            params = new(start)
            restore(params, state)
            for _ in range(SWITCH_ROUNDS):   # one material at a time may prefer another start (metal beside wood)
                if not _switch_starts(params, lambda p=params: float(objective(p))):
                    break
                _, state, more = run(params, cfg.start_iterations, bar)
                restore(params, state)
                curve0 = curve0 + more
            with torch.no_grad():
                initial_mae = float((pred(params) - target).abs().mean())
            final, state, curve1 = run(params, cfg.iterations, bar)
            restore(params, state)
            finals.append((final, start, params, state, initial_mae, curve0 + curve1))
        _, start, params, state, initial_mae, curve = min(finals, key=lambda t: t[0])
        restore(params, state)   # the device gains, shared by every start, back to this one's
        crossed = _cross_finals(params, [t[2] for t in finals if t[2] is not params],
                                lambda: float(objective(params))) if kept > 1 else 0
        if crossed:
            _, state, more = run(params, cross_steps, bar)
            restore(params, state)
            curve = curve + more
        else:
            bar.advance(cross_steps)
        with torch.no_grad():
            crossed_loss = float(objective(params))
    with torch.no_grad():
        mae = float((pred(params) - target).abs().mean())
    return PhysicalFitResult(params, mae, initial_mae, np.asarray(curve, dtype=np.float64), start[0],
                             time.time() - t0,
                             {"start_losses": {t[1][0]: t[0] for t in tried},
                              "final_losses": {t[1][0]: t[0] for t in finals},
                              "crossed_materials": crossed, "crossed_loss": crossed_loss,
                              "num_data": num_data, "num_unknowns": unknowns},
                             steps=steps_run[0])


def _num_unknowns(num_materials: int, cfg: PhysicalFitConfig, devices: DeviceGains | None) -> int:
    """The values a fit adjusts: eps_r, sigma (and thickness, and S) per material, S once when shared, the
    system gain when fitted, one gain per device."""
    per_material = 2 + (0 if cfg.half_space else 1) + (0 if cfg.shared_scattering else 1)
    return (num_materials * per_material + int(cfg.shared_scattering) + int(cfg.fit_gain)
            + (devices.num_fitted if devices is not None else 0))


def _unknowns_words(num_materials: int, cfg: PhysicalFitConfig, devices: DeviceGains | None) -> str:
    words = [plural(num_materials, "material") + " x " + ("eps_r, sigma" + ("" if cfg.half_space else ", thickness")
                                                         + ("" if cfg.shared_scattering else ", S"))]
    if cfg.shared_scattering:
        words.append("one S")
    if cfg.fit_gain:
        words.append("the system gain")
    if devices is not None and devices.num_fitted:
        words.append(plural(devices.num_fitted, "device gain"))
    return "; ".join(words)


def label_class_names(label_names: list[str]) -> list[str]:
    """Object class of each label name: the name without a trailing _NN (brick_03 -> brick, desk_12 ->
    desk). Objects of one class are taken to be of one material."""
    return [re.sub(r"_\d+$", "", str(n)) for n in label_names]


def material_index(kind: str, num_gaussians: int, labels: torch.Tensor | None, means: torch.Tensor | None = None,
                   normals: torch.Tensor | None = None, num_segments: int = 8, seed: int = 0,
                   label_names: list[str] | None = None) -> tuple[torch.Tensor, list[str]]:
    """(material of each Gaussian [G] int64, material names): one per "label", one per label "class"
    (label_class_names), one "global", or per "segment" (k-means on position, scaled by the scene
    extent, and normal, sign-free)."""
    if kind == "global":
        return torch.zeros(num_gaussians, dtype=torch.int64), ["scene"]
    if kind in ("label", "class"):
        if labels is None:
            raise ValueError(f"materials per {kind} need gaussians/labels in the scene")
        uniq, inv = torch.unique(labels, return_inverse=True)
        named = [label_names[u] if label_names is not None and 0 <= u < len(label_names) else f"label {u}"   # unnamed: a class each
                 for u in uniq.tolist()]
        if kind == "label":
            return inv, named
        classes = label_class_names(named)
        cnames = sorted(set(classes), key=classes.index)
        of_label = torch.as_tensor([cnames.index(c) for c in classes], dtype=torch.int64)
        return of_label[inv], cnames
    if kind == "segment":
        from scipy.cluster.vq import kmeans2
        x = means.numpy()
        extent = float(np.ptp(x, axis=0).max()) or 1.0
        n = normals.numpy()
        n = n * np.where(n[:, 2:3] < 0, -1.0, 1.0)       # normals are sign-free (two-sided surfels)
        feats = np.concatenate([x / extent, 0.5 * n], 1)
        k = max(1, min(num_segments, num_gaussians))
        _, lab = kmeans2(feats, k, seed=seed, minit="++")
        uniq, inv = np.unique(lab, return_inverse=True)
        return torch.as_tensor(inv, dtype=torch.int64), [f"segment {i}" for i in range(len(uniq))]
    raise ValueError(f"material sharing {kind!r} unknown (label, class, segment, global)")
