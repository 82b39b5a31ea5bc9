"""`rfir edit`: apply a list of edits (selection + operation) to an `rf` artifact and write a new one.

Every per-Gaussian array travels with delete/duplicate: gaussians/*, rf/* (not rf/freq_hz) and any
free-group dataset (model/, training/, effects/) whose first dimension is G. The edit history is
appended to provenance extra "edits" (earlier edits of the input are kept), each with its inverse.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.artifacts import check_output, read_artifact, write_artifact
from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_core.physics.materials import itu_law, power_law
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance

from rfir_stages.model.radio_model import quantity_of
from rfir_stages.predict.rssi_model_io import require_room_model

from .operations import EditScene, apply
from .script import Edit

# Datasets known not to be per-Gaussian even when their first dimension happens to equal G (tiny scenes).
NOT_PER_GAUSSIAN = {"rf/freq_hz", "training/loss_curve", "training/train_rows",
                    "training/fit_rows", "training/holdout_tx_ids"}
# the per-device gains; the room patches' grids (as many patches as Gaussians where each surfel is its own); the
# residual's training links (residual/surfel is per Gaussian); the per-material arrays (material/index is per
# Gaussian), which a model with as many materials as Gaussians must not lose
NOT_PER_GAUSSIAN_PREFIXES = ("model/device_", "model/patch_", "residual/tx_pos", "residual/rx_pos", "residual/weights_db",
                             "residual/mean_db", "material/eps_r", "material/sigma", "material/scattering",
                             "material/thickness", "material/gamma_normal")
_MOVES = ("translate", "rotate", "duplicate")


@dataclass
class EditResult:
    """Summary of one edit run. records: one history dict per edit; path is None on a dry run."""

    path: Path | None
    num_before: int
    num_after: int
    records: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    plot: Path | None = None
    radio_plot: Path | None = None
    radio_change: dict = field(default_factory=dict)
    # the frequency [Hz] of the radio change and whether it was the model's fitted one, taken because none was
    # asked for (freq_hz None)
    radio_freq_hz: float | None = None
    radio_freq_assumed: bool = False


def per_gaussian_keys(art) -> tuple[list[str], list[tuple[str, str]]]:
    """Names of the per-Gaussian datasets: (schema fields, (free group, dataset) pairs); first dimension G."""
    g = len(art["gaussians/means"])
    per_g = lambda name, v: (name not in NOT_PER_GAUSSIAN and not name.startswith(NOT_PER_GAUSSIAN_PREFIXES)  # noqa: E731
                             and np.ndim(v) >= 1 and len(v) == g)
    fields = [k for k, v in art.data.items() if per_g(k, v)]
    free = [(grp, k) for grp, content in art.free.items() if not grp.endswith("@attrs")
            for k, v in content.items() if per_g(f"{grp}/{k}", v)]
    return fields, free


def _check_paths(rf_path: Path, out_path: Path | None, dry_run: bool) -> None:
    if not rf_path.is_file():
        raise InputFileError("rf artifact not found", path=rf_path)
    if out_path is None:
        if not dry_run:
            raise ConfigError("-o/--out is required unless --dry-run")
        return
    if out_path.resolve() == rf_path.resolve() or (out_path.exists() and out_path.samefile(rf_path)):
        raise ConfigError(f"-o {out_path}: refusing to overwrite the input artifact; write the edited scene elsewhere")
    check_output(out_path, "rf", (rf_path,))


def _outside(means_m: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> int:
    """How many centres lie outside the box [lo, hi] (a 1e-9 m tolerance)."""
    return int(np.sum(np.any((means_m < lo - 1e-9) | (means_m > hi + 1e-9), axis=1)))


def run(rf_path, out_path, edits: list[Edit], *, dry_run: bool = False, allow_empty: bool = False, plot_path=None,
        map_tx=None, freq_hz: float | None = None, config_toml: str = "", progress=None) -> EditResult:
    """Apply `edits` in order to the rf artifact at rf_path; write out_path unless dry_run.

    A selection is evaluated on the scene as the earlier edits left it. An empty selection is an error
    unless allow_empty (or the edit's own allow_empty). Moving Gaussians outside the input's bounding
    box of centres gives a warning. plot_path: optional before/after top-view PNG; with it (and an
    artifact written) also the radio change beside it, PLOT_radio.png: the map of the Tx at map_tx
    [3] m before/after/difference for an RSSI model, RCS versus aspect before/after otherwise, at freq_hz Hz
    (None: the model's first fitted frequency; a room model refuses one outside its material laws' range, in one
    line, before anything is written)."""
    progress = progress or NullProgress()
    t0 = time.time()
    rf_path = Path(rf_path)
    out_path = Path(out_path) if out_path is not None else None
    _check_paths(rf_path, out_path, dry_run)
    if not edits:
        raise ConfigError("no edits: give --select and --op, or --script FILE")
    art = read_artifact(rf_path, "rf")
    if str(art.attrs.get("task", "")) == "rssi":
        require_room_model(art)   # one line naming the file and the model, for RSSI models rfir does not predict
    before_model = None
    if freq_hz is not None:
        freq_hz = _checked_frequency(freq_hz)
        if plot_path is not None and not dry_run and _is_room_model(art) and map_tx is not None:
            from rfir_stages.model.radio_model import load_model

            # loaded now so that a frequency outside its range is refused before the edited artifact is written
            before_model = load_model(art, quantity="rssi")
            try:
                before_model.predictor.check_frequencies([freq_hz])
            except ConfigError as err:
                raise ConfigError(f"--freq {freq_hz:g}: {err}") from None
    fields, free_keys = per_gaussian_keys(art)
    arrays = {k: np.array(art[k], copy=True) for k in fields}
    arrays.update({f"{g}/{k}": np.array(art.free[g][k], copy=True) for g, k in free_keys})
    names = [str(n) for n in art.attrs.get("label_names", [])]
    if "gaussians/labels" in arrays and arrays["gaussians/labels"].size:  # unnamed ids keep their numbers
        names += [f"label_{i}" for i in range(len(names), int(arrays["gaussians/labels"].max()) + 1)]
    scene = EditScene(arrays, label_names=names,
                      num_materials=len(art["material/eps_r"]) if "material/eps_r" in art.data else 0)
    before = np.array(arrays["gaussians/means"], copy=True)
    lo, hi = before.min(0), before.max(0)
    selected = np.zeros(len(before), bool)
    records, warnings = [], []
    with progress.task("edit", total=len(edits)) as bar:
        for i, edit in enumerate(edits, 1):
            mask = edit.select.mask(scene.arrays["gaussians/means"], scene.arrays.get("gaussians/labels"), scene.label_names)
            n = int(mask.sum())
            if n == 0 and edit.op is not None and not (allow_empty or edit.allow_empty):
                raise ConfigError(f"--select {edit.select.text}: selects none of {scene.count} Gaussians (edit {i}); "
                                  "pass --allow-empty to skip it")
            selected[scene.origin[mask]] = True
            rec = {"select": edit.select.text, "selected": n, "op": None, "inverse": None, "note": edit.note}
            if edit.op is not None:
                out_before = _outside(scene.arrays["gaussians/means"], lo, hi)
                rec.update(apply(scene, mask, edit.op))
                if edit.op.kind == "material" and n:
                    rec["op"] = f"{rec['op']} ({describe_new_material(art, scene)})"
                out_after = _outside(scene.arrays["gaussians/means"], lo, hi)
                if edit.op.kind in _MOVES and out_after > out_before:
                    rec["warnings"].append(f"{edit.op.text}: {out_after - out_before} Gaussians moved outside the scene "
                                           f"bounds {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} m")
                warnings += rec["warnings"]
                if scene.count == 0:
                    raise StageError(f"edit {i} ({edit.op.text}) deletes every Gaussian; nothing would be left to predict")
            records.append(rec)
            bar.advance(1)
    drop_residual = "residual/tx_pos" in art.data and any(r["op"] is not None for r in records)
    if drop_residual:   # its corrections describe the unedited scene's links (docs/guide/edit.md)
        warnings.append("the model's residual (a correction of the unedited scene's training links in link "
                        "geometry) is dropped: the edited scene is predicted by the physics alone")
    result = EditResult(None, len(before), scene.count, records, warnings)
    if plot_path is not None:
        from .plot import top_view

        result.plot = top_view(Path(plot_path), before, selected, scene.arrays["gaussians/means"], scene.touched,
                               title=f"{rf_path.name}: " + "; ".join(f"{e.select.text} -> {e.op.text if e.op else 'list'}"
                                                                     for e in edits)[:160])
    if not dry_run:
        result.path = _write(out_path, rf_path, art, scene, records, config_toml, t0, drop_residual)
        if plot_path is not None:
            result.radio_plot, result.radio_change = _radio_change(Path(plot_path), art, result.path, map_tx, freq_hz,
                                                                   before_model)
            if result.radio_plot is not None:
                result.radio_freq_hz = result.radio_change["freq_hz"]
                result.radio_freq_assumed = freq_hz is None
    if freq_hz is not None and result.radio_plot is None:
        result.warnings.append("--freq: no radio change was drawn (it needs --plot, an artifact written, and --map-tx "
                               "for an RSSI model)")
    return result


def _checked_frequency(freq_hz) -> float:
    """freq_hz as a float [Hz]; a ConfigError (one line) unless a positive finite number."""
    f = float(freq_hz)
    if not (np.isfinite(f) and f > 0):
        raise ConfigError(f"--freq: expected a positive frequency in hertz, got {freq_hz}")
    return f


def _is_room_model(art) -> bool:
    return quantity_of(art) == "rssi"   # a model of links in a room: its radio change is a map


def _radio_change(plot_path: Path, art, edited_path: Path, map_tx, freq_hz: float | None = None, before_model=None):
    """(PNG, summary) of the radio change at freq_hz Hz (None: the fitted frequency), or (None, {}) for an RSSI
    model without map_tx; before_model: the input's RadioModel when already loaded."""
    from .map_change import rcs_change, rssi_map_change

    target = plot_path.with_name(plot_path.stem + "_radio.png")
    after = read_artifact(edited_path, "rf")
    if _is_room_model(art):
        if map_tx is None:
            return None, {}
        return target, rssi_map_change(target, art if before_model is None else before_model, after,
                                       np.asarray(map_tx, np.float64), freq_hz=freq_hz)
    if str(art.attrs.get("task", "")) in ("rcs", "wideband") and not art.free.get("model@attrs", {}).get("wideband"):
        return target, rcs_change(target, art, after, freq_hz=freq_hz)
    return None, {}


def _write(out_path: Path, rf_path: Path, art, scene: EditScene, records: list, config_toml: str, t0: float,
           drop_residual: bool = False) -> Path:
    data = dict(art.data)
    data.update({k: v for k, v in scene.arrays.items() if k in data or k == "gaussians/labels"})
    if drop_residual:
        data = {k: v for k, v in data.items() if not k.startswith("residual/")}
    attrs = dict(art.attrs)
    if scene.label_names:
        attrs["label_names"] = np.asarray(scene.label_names, dtype=object)
    free = art.free_for_write()
    for group, content in free.items():   # per-Gaussian datasets follow the edit
        content.update({k: scene.arrays[f"{group}/{k}"] for k in content if f"{group}/{k}" in scene.arrays})
    if scene.new_materials:
        append_materials(data, free, scene)
    if drop_residual:
        model = free.setdefault("model", {}).setdefault("@attrs", {})
        was = model.get("residual.chosen", "")
        for key in [k for k in model if k.startswith("residual.")]:   # the dropped form's lengths and weight
            del model[key]
        model.update({"residual.form": "off", "residual.chosen": f"dropped by edit (was {was})"})
    up = art.provenance
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    history = list(up.extra.get("edits", [])) + [dict(r, input=str(rf_path), time=stamp) for r in records]
    prov = Provenance(stage="edit", config_toml=config_toml, extra={
        "edits": history, "upstream": {"stage": up.stage, "command": up.command, "inputs": up.inputs,
                                       "extra": {k: v for k, v in up.extra.items() if k not in ("edits", "upstream")}}})
    prov.add_input(rf_path)
    prov.wall_time_s = time.time() - t0
    return write_artifact(out_path, "rf", data, attrs=attrs, provenance=prov, free=free)


def append_materials(data: dict, free: dict, scene: EditScene) -> None:
    """Append the materials that `material:NAME` edits created to the physical model's material/* arrays
    (ITU law at each fitted frequency; thickness and S of the material each replaces) and refresh the
    attribute-map values (rf/gamma_abs, rf/gamma_phase_rad) of every Gaussian."""
    import torch

    from rfir_stages.model.physical import MaterialValues

    attrs = free.setdefault("model", {}).setdefault("@attrs", {})
    freqs = np.asarray(data["rf/freq_hz"], np.float64)
    exponent = float(attrs.get("sigma_exponent", 1.0))
    names = [str(n) for n in np.atleast_1d(attrs.get("material_names", []))]
    for key, was in scene.new_materials:
        for name, value in new_material_values(data, key, was, exponent).items():
            data[f"material/{name}"] = np.append(np.asarray(data[f"material/{name}"], np.float64), value)
        names.append(key)
    t = lambda k: torch.as_tensor(np.asarray(data[k], np.float64))  # noqa: E731
    th = t("material/thickness_m")
    vals = MaterialValues(t("material/eps_r"), t("material/sigma_1ghz_s_per_m"), exponent, t("material/scattering"),
                          None if bool((th <= 0).all()) else th.clamp(min=1e-6))
    r = vals.normal_reflection(torch.as_tensor(freqs)).numpy()                     # [N, F]
    data["material/gamma_normal_abs"] = np.abs(r)
    if scene.new_materials:   # the links' ranges describe fitted materials; an ITU material was not fitted
        data.pop("material/gamma_normal_range", None)
    index = scene.arrays["material/index"]
    data["rf/gamma_abs"], data["rf/gamma_phase_rad"] = np.abs(r[index, 0]), np.angle(r[index, 0])
    attrs["material_names"] = np.asarray(names, dtype=object)


def new_material_values(data: dict, key: str, was: int, exponent: float = 1.0) -> dict:
    """material/* values of the ITU-R P.2040 material `key` that replaces material `was` (its index in
    data's material/* arrays): eps_r and sigma from the ITU law at the model's first frequency (sigma
    referred to 1 GHz with the model's exponent); thickness and scattering coefficient S kept from `was`.

    S stays because it describes the surface, not its bulk material: in the effective-roughness model
    the specular share sqrt(1 - S^2) is set by the surface's height profile (docs/physics.md section 8.8),
    which an edit of the material does not change."""

    f = float(np.asarray(data["rf/freq_hz"], np.float64)[0])
    eps, sigma = itu_law(key, f)
    return {"eps_r": float(eps), "sigma_1ghz_s_per_m": float(sigma) / power_law(1.0, exponent, f),
            "scattering": float(data["material/scattering"][was]), "thickness_m": float(data["material/thickness_m"][was])}


def describe_new_material(art, scene: EditScene) -> str:
    """What the last `material:NAME` edit of scene assumed, in words (printed with the edit, kept in its history)."""
    key, was = scene.new_materials[-1]
    while was >= scene.num_materials:           # re-materialled twice: S and thickness come from the first
        was = scene.new_materials[was - scene.num_materials][1]
    model = art.free.get("model@attrs", {})
    names = [str(n) for n in np.atleast_1d(model.get("material_names", []))]
    v = new_material_values(art.data, key, was, float(model.get("sigma_exponent", 1.0)))
    f = float(np.asarray(art["rf/freq_hz"], np.float64)[0])
    sigma = power_law(v["sigma_1ghz_s_per_m"], float(model.get("sigma_exponent", 1.0)), f)
    replaced = names[was] if was < len(names) else f"material {was}"
    return (f"ITU-R P.2040 {key} at {f / 1e9:.3g} GHz: eps_r {v['eps_r']:.3g}, sigma {sigma:.3g} S/m; "
            f"thickness {v['thickness_m'] * 1e3:.3g} mm and S {v['scattering']:.2f} kept from {replaced}")
