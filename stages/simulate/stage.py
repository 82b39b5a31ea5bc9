"""`run(...)`: make a ground-truth data set for one scene (meshes, photos, radio measurements)."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, StageError
from rfir_core.progress import NullProgress

from rfir_core.physics.antennas import horn_boresight_gain, horn_exponent
from .measurement import MeasurementEffects, apply_measurement_effects
from .scene_edits import RECORD_SEPARATOR, apply_scene_edits
from .scenes import SceneSpec, build_scene, write_meshes
from .settings import RSSI_ANTENNAS, SimulateSettings, parse_settings
from .solve import rcs_dbsm_from_gain

TASKS = ("rssi", "rcs", "wideband")


@dataclass
class SimulateResult:
    """What `run` wrote."""

    scene: str
    out_dir: Path
    measurements: dict[str, Path] = field(default_factory=dict)  # task -> artifact
    links: dict[str, int] = field(default_factory=dict)  # task -> number of links
    freqs: dict[str, int] = field(default_factory=dict)  # task -> number of frequencies
    meshes: list[Path] = field(default_factory=list)
    cameras: Path | None = None
    images: int = 0
    timings_s: dict[str, float] = field(default_factory=dict)
    backends: dict[str, str] = field(default_factory=dict)  # task -> solver ("sionna", "po")
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what was assumed or dropped, one line each


def default_tasks(spec: SceneSpec) -> list[str]:
    if spec.kind == "room":
        return ["rssi"]
    if spec.name == "h-target":
        return ["rcs", "wideband"]
    return ["rcs"]


def artifact_name(task: str, tasks: list[str]) -> str:
    """measurements.h5 for the first task, measurements_<task>.h5 for the others."""
    return "measurements.h5" if task == tasks[0] else f"measurements_{task}.h5"


def run(scene: str, out_dir, config: dict | None = None, *, config_toml: str = "", quick: bool | None = None,
        progress=None) -> SimulateResult:
    """Simulate `scene` into `out_dir`.

    config: the [simulate] table (defaults from configs/simulate.toml when None).
    quick: overrides config["quick"] when given.
    """
    progress = progress or NullProgress()
    try:
        spec = build_scene(scene)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    except ImportError as exc:
        raise StageError(str(exc)) from None
    settings = parse_settings(config, quick=quick, scene=spec.name)
    if settings.scene_edits:
        apply_scene_edits(spec, settings.scene_edits)
        spec.info["scene_edits"] = list(settings.scene_edits)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = SimulateResult(scene=spec.name, out_dir=out)
    tasks = default_tasks(spec) if settings.tasks == ["auto"] else list(settings.tasks)
    for t in tasks:
        if t not in TASKS:
            raise ConfigError(f"simulate.tasks: unknown task {t!r} (known: {', '.join(TASKS)})")
        if t == "rssi" and spec.kind != "room" or t in ("rcs", "wideband") and spec.kind != "object":
            raise ConfigError(f"task {t!r} does not fit scene {spec.name!r} ({spec.kind})")

    t0 = time.time()
    result.meshes = write_meshes(spec, out / "meshes")
    result.timings_s["meshes"] = time.time() - t0

    if settings.photos:
        _photos(spec, out, settings, result, progress)

    if tasks:
        from .radio_scene import load_radio_scene, write_radio_xml

        radio = None
        if any(t == "rssi" or settings.rcs_backend == "sionna" for t in tasks):
            try:
                radio = load_radio_scene(spec, out / "radio", 2.4e9, settings.material_effects())
            except ImportError as exc:
                raise StageError(f"the radio simulator needs sionna-rt ({exc}); pip install 'rfir[sim]'") from None
        elif spec.objects:
            write_radio_xml(spec, out / "radio")  # the radio scene is part of the output either way
        for task in tasks:
            t0 = time.time()
            path = out / artifact_name(task, tasks)
            n_links, n_f = _radio_task(task, spec, radio, settings, path, config_toml, progress, out / "radio",
                                     result.notes)
            result.measurements[task] = path
            result.links[task] = n_links
            result.freqs[task] = n_f
            result.backends[task] = "sionna" if task == "rssi" else settings.rcs_backend
            result.timings_s[task] = time.time() - t0
    return result


def _photos(spec, out, settings, result, progress) -> None:
    try:
        from rfir_stages.render import render_views
    except ImportError:
        result.warnings.append("photos skipped: rfir_stages.render.render_views is not available")
        return
    t0 = time.time()
    rendered = render_views(spec, out, view_count(spec.kind, settings.num_views), settings.image_width,
                            settings.image_height, settings.seed, progress)
    result.timings_s["photos"] = time.time() - t0
    result.cameras = Path(rendered.cameras_path)
    result.images = len(rendered.image_paths)


def _radio_task(task, spec, radio, settings: SimulateSettings, path: Path, config_toml: str, progress, folder,
                notes: list[str]):
    from rfir_core.artifacts import write_artifact
    from rfir_core.provenance import Provenance

    prov = Provenance(stage="simulate", config_toml=config_toml)
    started = time.time()
    backend = "sionna" if task == "rssi" else settings.rcs_backend
    if task == "rssi":
        data, sim_attrs = _rssi(spec, radio, settings, progress, notes)
    elif backend == "po":
        data, sim_attrs = _rcs_po(task, spec, settings, progress)
    else:
        data, sim_attrs = _rcs(task, spec, radio, settings, progress, folder)
    meas: MeasurementEffects = settings.measurement
    rng = np.random.default_rng(settings.seed + 1)
    gain_db, channel = apply_measurement_effects(data.pop("_power"), data["channel"], data["freq_hz"], meas, rng)
    data["channel"] = channel
    data["path_gain_db"] = gain_db
    if task != "rssi" and meas.aspect_offset_deg != 0.0:
        _misrecord_aspects(data, spec, meas.aspect_offset_deg)
    if task != "rssi":
        data["rcs_dbsm"] = rcs_dbsm_from_gain(10 ** (gain_db / 10), data["range_m"], data["freq_hz"],
                                              horn_boresight_gain(settings.horn_hpbw_deg))
    data["scene_bounds"] = np.asarray(spec.bounds, float)
    prov.wall_time_s = time.time() - started
    effects = settings.effects_dict(backend)
    prov.extra = {"task": task, "effects": effects, "sim": {k: v for k, v in sim_attrs.items()
                                                              if not isinstance(v, np.ndarray)}}
    if settings.scene_edits:
        sim_attrs = dict(sim_attrs, scene_edits=RECORD_SEPARATOR.join(settings.scene_edits))
    sim_group = {"@attrs": {**_flat_attrs(effects), **{k: v for k, v in sim_attrs.items()
                                                        if not isinstance(v, np.ndarray)}}}
    sim_group.update({k: v for k, v in sim_attrs.items() if isinstance(v, np.ndarray)})
    root = {"task": "wideband" if task == "wideband" else task, "scene": spec.name}
    if task == "rssi":   # the antennas simulated, as a measurement file states them (docs/artifacts.md)
        root.update(antenna_tx=RSSI_ANTENNAS[settings.rssi_antenna], antenna_rx=RSSI_ANTENNAS[settings.rssi_antenna],
                    polarisation="V")
    write_artifact(path, "measurements", data, attrs=root,
                   provenance=prov, free={"simulator": sim_group})
    return len(data["tx_pos"]), len(data["freq_hz"])


def _misrecord_aspects(data: dict, spec, offset_deg: float) -> None:
    """A turntable offset: the recorded aspects, and the radar positions computed from them, are off
    by offset_deg from the ones simulated (in place)."""
    centre = 0.5 * (np.asarray(spec.bounds[0]) + np.asarray(spec.bounds[1]))
    asp = np.asarray(data["aspect_rad"], np.float64)
    ang = np.arctan2(data["tx_pos"][:, 1] - centre[1], data["tx_pos"][:, 0] - centre[0])
    # the radar turns with the aspect or against it, depending on the convention: keep whichever holds
    same = np.abs(np.angle(np.exp(1j * (ang - asp))) - np.angle(np.exp(1j * (ang[0] - asp[0])))).max() < 1e-6
    turn = math.radians(offset_deg) * (1.0 if same else -1.0)
    c, s_ = math.cos(turn), math.sin(turn)
    rot = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    for key in ("tx_pos", "rx_pos"):
        data[key] = (np.asarray(data[key]) - centre) @ rot.T + centre
    data["aspect_rad"] = np.mod(asp + math.radians(offset_deg), 2 * math.pi)


def _flat_attrs(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat_attrs(v, key + "."))
        elif isinstance(v, (list, tuple)):
            out[key] = np.asarray(v)
        else:
            out[key] = v
    return out


def rssi_grids(spec, s: SimulateSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Transmitter [T, 3] and receiver [R, 3] grid positions (m) of the rssi task, and for each a [T] / [R]
    bool: the point keeps clearance_m from every object's bounding box (not inside furniture or against it)."""
    from .rssi import clear_of_objects, grid_positions

    out = []
    for what, grid, height, margin in (("transmitter", s.tx_grid, s.tx_height_m, s.tx_margin_m),
                                       ("receiver", s.rx_grid, s.rx_height_m, s.rx_margin_m)):
        pts = grid_positions(spec.bounds, *grid, height, margin)
        clear = clear_of_objects(spec, pts, s.clearance_m)
        if not clear.any():
            raise ConfigError(f"simulate.rssi: every {what} grid point lies within clearance_m = {s.clearance_m:g} m "
                              f"of an object of scene {spec.name!r}")
        out += [pts, clear]
    return out[0], out[2], out[1], out[3]


def _rssi(spec, radio, s: SimulateSettings, progress, notes: list[str]):
    """(measurement fields, simulator attributes) of the rssi task; appends to notes what it dropped.

    The whole grids are solved and the split drawn over all their links before the points without
    clearance are dropped: the links kept are exactly those of a solve without the clearance (Sionna's
    sampling depends on the set of receivers), with the same split."""
    from .rssi import simulate_rssi

    tx, rx, tx_clear, rx_clear = rssi_grids(spec, s)
    freqs = np.asarray(s.rssi_freqs_hz, float)
    import sionna.rt as rt

    # every antenna Sionna RT's simulate.rssi.antenna pattern, V-polarised (the other tasks' stay isotropic)
    arrays = radio.tx_array, radio.rx_array
    radio.tx_array, radio.rx_array = (rt.PlanarArray(num_rows=1, num_cols=1, pattern=s.rssi_antenna, polarization="V")
                                      for _ in range(2))
    try:
        channel, power, tx_id, rx_id, n_paths, cap_hits = simulate_rssi(radio, tx, rx, freqs, s.physics_for("rssi"),
                                                                        progress, f"RSSI {len(tx)} Tx x {len(rx)} Rx",
                                                                        channels_hz=s.rssi_channels_hz)
    finally:
        radio.tx_array, radio.rx_array = arrays
    if s.rssi_channels_hz:
        notes.append(f"each link's power is the mean over {len(s.rssi_channels_hz)} channels ("
                     + ", ".join(f"{c / 1e9:.3f}" for c in s.rssi_channels_hz)
                     + f" GHz) of the paths solved at {freqs[0] / 1e9:.3f} GHz")
    rng = np.random.default_rng(s.seed)
    n = len(tx_id)
    split = np.zeros(n, np.int64)
    test = rng.permutation(n)[: int(round(s.test_fraction * n))]
    split[test] = 1
    keep = tx_clear[tx_id] & rx_clear[rx_id]
    for what, clear in (("transmitter", tx_clear), ("receiver", rx_clear)):
        if not clear.all():
            notes.append(f"dropped {int((~clear).sum())} of {len(clear)} {what} grid points within "
                         f"{s.clearance_m:g} m of an object's bounding box (inside furniture or against it)")
    channel, power, n_paths, split = channel[keep], power[keep], n_paths[keep], split[keep]
    tx_id = (np.cumsum(tx_clear) - 1)[tx_id[keep]]                      # ids of the kept points, 0..T'-1
    rx_id = (np.cumsum(rx_clear) - 1)[rx_id[keep]]
    tx, rx = tx[tx_clear], rx[rx_clear]
    data = {"tx_pos": tx[tx_id], "rx_pos": rx[rx_id], "freq_hz": freqs, "channel": channel, "_power": power,
            "tx_id": tx_id.astype(np.int64), "rx_id": rx_id.astype(np.int64), "split": split}
    pattern = f"{RSSI_ANTENNAS[s.rssi_antenna]} (Sionna RT pattern {s.rssi_antenna!r}, V-pol)"
    attrs = {"backend": "sionna-rt", "antenna_tx": pattern, "antenna_rx": pattern,
             "split_protocol": f"random {1 - s.test_fraction:.0%}/{s.test_fraction:.0%}, seed {s.seed}",
             "split_seed": int(s.seed), "num_tx": len(tx), "num_rx": len(rx), "clearance_m": float(s.clearance_m),
             "num_paths": n_paths,
             "paths_cap_hits": int(cap_hits), "num_solves": int(len(tx) * len(freqs))}
    if s.rssi_channels_hz:   # rf-fit reads it: a sum over channels is not one frequency's coherent sum
        attrs["channels_hz"] = ",".join(f"{c:.9g}" for c in s.rssi_channels_hz)
    return data, attrs


def _rcs_plan(task, spec, s: SimulateSettings):
    """Aspects, ranges, solve frequencies and output frequencies of an rcs / wideband task."""
    from .rcs import aspect_grid, wideband_plan

    if task == "rcs":
        aspects = aspect_grid(s.aspect_step_deg)
        ranges = np.asarray(s.ranges_m, float)
        solve_f = np.asarray(s.rcs_freqs_hz, float)
        out_f = [np.array([f]) for f in solve_f]
        label = f"RCS {spec.name} {len(aspects)} aspects x {len(ranges)} ranges x {len(solve_f)} freqs"
    else:
        aspects = aspect_grid(s.wideband_aspect_step_deg)
        ranges = np.array([s.wideband_range_m])
        solve_f, out_f = wideband_plan(s.wideband_centre_hz, s.wideband_bandwidth_hz, s.wideband_num_freqs,
                                       s.wideband_num_anchors)
        label = f"wideband {spec.name} {len(aspects)} aspects x {sum(map(len, out_f))} freqs"
    return aspects, ranges, solve_f, out_f, label


def _rcs_data(task, grid, out_f, raw, s: SimulateSettings) -> dict:
    asp, rng_m, _ = grid.links()
    tx, rx = grid.tx_rx()
    freqs = np.concatenate([np.atleast_1d(f) for f in out_f])
    aspect_idx = np.rint(np.rad2deg(asp) / (s.aspect_step_deg if task == "rcs" else s.wideband_aspect_step_deg))
    split = (aspect_idx.astype(np.int64) % 2).astype(np.int64)  # even aspects train, odd test
    return {"tx_pos": tx, "rx_pos": rx, "freq_hz": freqs, "channel": raw.channel, "_power": raw.power,
            "aspect_rad": asp, "range_m": rng_m, "split": split,
            "tx_id": np.arange(len(tx), dtype=np.int64), "rx_id": np.arange(len(tx), dtype=np.int64)}


def _antenna_attrs(s: SimulateSettings) -> dict:
    return {"antenna_tx": "horn", "antenna_rx": "horn",
            "antenna_pattern": "cos^q over the front hemisphere, G0 = 2 (q + 1) (rfir_core.physics.antennas)",
            "horn_hpbw_deg": float(s.horn_hpbw_deg), "horn_q": float(horn_exponent(s.horn_hpbw_deg)),
            "horn_boresight_gain_dbi": float(10 * math.log10(horn_boresight_gain(s.horn_hpbw_deg))),
            "geometry": "object fixed at origin; aspect theta = radar at azimuth -theta",
            "tx_rx_separation_m": float(s.separation_m), "split_protocol": "even aspect index train, odd test"}


def _rcs(task, spec, radio, s: SimulateSettings, progress, folder):
    from .rcs import RadarGrid, object_radius, simulate_monostatic

    aspects, ranges, solve_f, out_f, label = _rcs_plan(task, spec, s)
    if task == "wideband":
        label += f" ({len(solve_f)} solves)"
    grid = RadarGrid(aspects, ranges, np.zeros(3), s.separation_m)
    workers = max(1, min(int(s.workers), len(aspects) * len(ranges) * len(solve_f)))
    raw = simulate_monostatic(radio, grid, object_radius(spec), solve_f, out_f, s.physics_for("rcs"),
                              s.horn_hpbw_deg, s.focused_sampling, progress, label, workers=workers,
                              radio_xml=Path(folder) / f"{spec.name}.xml", material_effects=s.material_effects(),
                              worker_timeout_s=s.worker_timeout_s)
    data = _rcs_data(task, grid, out_f, raw, s)
    attrs = {"backend": "sionna-rt", **_antenna_attrs(s),
             "focused_sampling": bool(raw.focused), "num_solves": int(raw.solves),
             "paths_cap_hits": int(raw.cap_hits), "workers": int(workers),
             "num_paths": raw.num_paths, "num_diffuse_paths": raw.num_diffuse}
    if task == "wideband":
        attrs["wideband_anchor_freqs_hz"] = np.asarray(solve_f, float)
        attrs["wideband_note"] = ("Sionna re-run at each anchor (materials and paths exact there); other "
                                  "frequencies use the anchor's paths with exact per-path delay phase and "
                                  "lambda-scaled amplitude")
    return data, attrs


def _rcs_po(task, spec, s: SimulateSettings, progress):
    from .po_backend import simulate_monostatic_po
    from .rcs import RadarGrid

    aspects, ranges, _, out_f, label = _rcs_plan(task, spec, s)
    grid = RadarGrid(aspects, ranges, np.zeros(3), s.separation_m)
    freqs = np.concatenate([np.atleast_1d(f) for f in out_f])
    raw, po_prov = simulate_monostatic_po(spec, grid, freqs, s.horn_hpbw_deg, s.po, progress, label + " (PO)")
    data = _rcs_data(task, grid, out_f, raw, s)
    attrs = {"backend": "po", **_antenna_attrs(s),
             **{f"po.{k}": ("auto" if v is None else v) for k, v in po_prov.items() if k != "backend"},
             "num_solves": 1, "num_aspects": int(len(data["tx_pos"])), "num_freqs": int(len(freqs))}
    attrs = {k: (np.asarray(v) if isinstance(v, list) else v) for k, v in attrs.items()}
    if task == "wideband":
        attrs["wideband_note"] = ("PO solved at every frequency (exact k, Fresnel coefficients per frequency); "
                                  "facet geometry, lit sets and multiple-bounce tubes shared across frequencies")
    return data, attrs


DEFAULT_VIEWS = {"object": 60, "room": 120}


def view_count(scene_kind: str, configured: int) -> int:
    """Photos to render: the configured count, or the scene kind's default when it is 0."""
    if configured < 0:
        raise ValueError(f"simulate.num_views must be >= 0, got {configured}")
    return configured or DEFAULT_VIEWS.get(scene_kind, 120)
