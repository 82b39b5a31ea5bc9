"""Measured-like RSSI from a simulated one: what real measurements have and a simulation lacks.

    python scripts/measured_like.py SIM_DIR OUT_DIR [--seed N] [--set simulate.measured_like.KEY=VALUE]

SIM_DIR is the output of `rfir simulate SCENE SIM_DIR` for a room scene whose SceneSpec.info names a
floor plan (the `flat`); settings in `[simulate.measured_like]` (configs/simulate.toml). Each effect
is drawn from its own stream of the seed, so changing one setting leaves the others' draws alone:

- ends swapped (`swap_ends`): the simulator's few transmitters become the fixed receivers of a
  measurement and its many receivers the transmitter positions (a tag carried around). Path gain
  between isotropic antennas is reciprocal, so the swap changes no value.
- positions closer than `clearance_m` to an object of the true scene (walls, furniture) are dropped,
  with their links: nobody measures inside a fridge or a wall.
- per-device gains [dB]: each transmitter position and each receiver a fixed offset drawn from
  N(0, tx_gain_std_db) and N(0, rx_gain_std_db) (a tag held differently at each position, each
  receiver's own radio and cable).
- unknown antenna patterns: every device has the pattern G(psi) = (f + (1 - f) ((1 + cos psi) / 2)^q)
  / (f + (1 - f) / (q + 1)) (q `pattern_exponent`, f `pattern_floor`; normalised to a mean of 1 over
  the sphere, so it adds no average gain) about a boresight drawn uniformly on the sphere. The
  patterns weight each link by the gains toward the other end (the direct direction): the
  simulation's total per link carries no path directions, so power arriving from elsewhere is
  weighted the same (this understates what a pattern does to reflected power).
- fading: log-normal, N(0, fading_std_db) dB per link, independent between links.
- geometry for rfir: OUT_DIR/floorplan/<scene>_floorplan.ply (+ labels.json) holds only what a floor
  plan shows (SceneSpec.info["floorplan"]: shell, walls, windows, doors; no furniture) under the
  plan's names, which name no material; interior walls (info["interior_walls"]) moved along their
  normal by N(0, plan_error_std_m) each (a plan places partitions to a few centimetres).
- splits (rfir_stages.model.split_protocols): measurements_random.h5 (`random:F`), measurements_room.h5
  (`holdout_box` of info["rooms"][holdout_room]: every transmitter in that room tests) and
  measurements_rx.h5 (`holdout_rx:N`): the same rows, each with its `split` column.

The drawn truth (gains, boresights, fading and pattern per link, plan offsets) goes to
OUT_DIR/truth.json, for scoring only: the measurement files do not carry it (no antenna is stated,
so rf-fit assumes isotropic antennas and says so).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError
from rfir_stages.model.split_protocols import describe, protocol_masks

from .rssi import clear_of_objects
from .scenes import SceneSpec, build_scene, write_ply

STREAMS = ("plan", "tx_gain", "rx_gain", "tx_boresight", "rx_boresight", "fading", "splits")
PROTOCOL_FILES = {"random": "measurements_random.h5", "room": "measurements_room.h5", "rx": "measurements_rx.h5"}


@dataclass(frozen=True)
class MeasuredLikeSettings:
    """[simulate.measured_like]; dB for gains and fading, metres for lengths (module docstring)."""

    swap_ends: bool
    clearance_m: float
    tx_gain_std_db: float
    rx_gain_std_db: float
    fading_std_db: float
    pattern_exponent: float
    pattern_floor: float
    plan_error_std_m: float
    random_fraction: float
    holdout_room: str
    holdout_rx: int


def parse_settings(table: dict) -> MeasuredLikeSettings:
    """Settings from the [simulate.measured_like] table; one line naming a missing, unknown or bad key."""
    names = [f.name for f in fields(MeasuredLikeSettings)]
    unknown = sorted(set(table) - set(names))
    missing = [n for n in names if n not in table]
    if unknown or missing:
        raise ConfigError(f"simulate.measured_like: unknown key(s) {', '.join(unknown) or '-'}, "
                          f"missing key(s) {', '.join(missing) or '-'}")
    try:
        s = MeasuredLikeSettings(**{f.name: _coerce(f.type, table[f.name]) for f in fields(MeasuredLikeSettings)})
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"simulate.measured_like: bad value ({exc})") from None
    if min(s.tx_gain_std_db, s.rx_gain_std_db, s.fading_std_db, s.plan_error_std_m, s.clearance_m) < 0:
        raise ConfigError("simulate.measured_like: standard deviations and clearance_m must be >= 0")
    if not 0.0 <= s.pattern_floor <= 1.0 or s.pattern_exponent < 0:
        raise ConfigError("simulate.measured_like: pattern_floor must be in [0, 1] and pattern_exponent >= 0")
    if not 0.0 < s.random_fraction < 1.0 or s.holdout_rx < 1:
        raise ConfigError("simulate.measured_like: random_fraction must be in (0, 1) and holdout_rx >= 1")
    return s


def _coerce(kind: str, value):
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"{value!r} is not true or false")
        return value
    return {"float": float, "int": int, "str": str}[kind](value)


def pattern_gain(cos_psi, exponent: float, floor: float) -> np.ndarray:
    """Linear gain [same shape] of the devices' pattern at cos(angle off boresight); mean 1 over the sphere.

    The mean of ((1 + c) / 2)^q over the sphere (c uniform on [-1, 1]) is 1 / (q + 1)."""
    c = np.clip(np.asarray(cos_psi, np.float64), -1.0, 1.0)
    return (floor + (1.0 - floor) * ((1.0 + c) / 2.0) ** exponent) / (floor + (1.0 - floor) / (exponent + 1.0))


def random_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """[n, 3] unit vectors uniform on the sphere."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def floorplan_mesh(spec: SceneSpec, rng: np.random.Generator, error_std_m: float):
    """(vertices, faces, face labels, plan names, {plan name: offset m}) of what the floor plan shows."""
    plan = spec.info.get("floorplan")
    if not plan:
        raise ConfigError(f"scene {spec.name!r} has no floor plan (SceneSpec.info['floorplan']); known: flat")
    by_name = {o.name: o for o in spec.objects}
    interior = set(spec.info.get("interior_walls", []))
    offsets = {}
    vs, fs, fl, names, off = [], [], [], [], 0
    for label, (true_name, plan_name) in enumerate(plan.items()):
        o = by_name[true_name]
        v = o.vertices.copy()
        if true_name in interior:
            shift = float(rng.normal(0.0, error_std_m))
            v += shift * o.face_normals()[0]
            offsets[plan_name] = shift
        vs.append(v)
        fs.append(o.faces + off)
        fl.append(np.full(len(o.faces), label, np.int32))
        names.append(plan_name)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(fl), names, offsets


def _streams(seed: int) -> dict:
    kids = np.random.SeedSequence(int(seed)).spawn(len(STREAMS))
    return {name: np.random.default_rng(k) for name, k in zip(STREAMS, kids)}


def protocols(spec: SceneSpec, s: MeasuredLikeSettings) -> dict:
    """{key: protocol string of rfir_stages.model.split_protocols} for the three files."""
    rooms = spec.info.get("rooms", {})
    if s.holdout_room not in rooms:
        raise ConfigError(f"simulate.measured_like.holdout_room = {s.holdout_room!r}: scene {spec.name!r} has rooms "
                          f"{', '.join(rooms) or 'none'}")
    x0, x1, y0, y1 = rooms[s.holdout_room]
    return {"random": f"random:{s.random_fraction:g}", "room": f"holdout_box:{x0:g}:{x1:g}:{y0:g}:{y1:g}",
            "rx": f"holdout_rx:{s.holdout_rx:d}"}


def transform(data: dict, spec: SceneSpec, s: MeasuredLikeSettings, seed: int) -> tuple[dict, dict, list[str]]:
    """(measurement fields without split, truth, lines saying what was done) from simulated rssi fields.

    data: tx_pos [L, 3], rx_pos [L, 3], tx_id [L], rx_id [L], freq_hz [1], path_gain_db [L, 1], channel
    [L, 1] (optional), scene_bounds (optional)."""
    rng = _streams(seed)
    say = []
    tx, rx = np.asarray(data["tx_pos"], np.float64), np.asarray(data["rx_pos"], np.float64)
    tid, rid = np.asarray(data["tx_id"], np.int64), np.asarray(data["rx_id"], np.int64)
    pg = np.asarray(data["path_gain_db"], np.float64)
    if pg.ndim != 2 or pg.shape[1] != 1:
        raise InputFileError(f"path_gain_db has shape {pg.shape}; measured-like data take one frequency")
    if s.swap_ends:
        tx, rx, tid, rid = rx, tx, rid, tid
        say.append("ends swapped: the simulator's transmitters are the receivers, its receivers the transmitter "
                   "positions (path gain between isotropic antennas is reciprocal)")
    ok = clear_of_objects(spec, tx, s.clearance_m) & clear_of_objects(spec, rx, s.clearance_m) & (pg[:, 0] > -200.0)
    n_tx0, n_rx0 = len(np.unique(tid)), len(np.unique(rid))
    tx, rx, tid, rid, pg = tx[ok], rx[ok], tid[ok], rid[ok], pg[ok]
    channel = None if data.get("channel") is None else np.asarray(data["channel"])[ok]
    _, tid = np.unique(tid, return_inverse=True)
    _, rid = np.unique(rid, return_inverse=True)
    n_tx, n_rx = int(tid.max()) + 1, int(rid.max()) + 1
    say.append(f"dropped {n_tx0 - n_tx} of {n_tx0} transmitter and {n_rx0 - n_rx} of {n_rx0} receiver positions "
               f"within {s.clearance_m:g} m of an object of the true scene (bounding boxes): {n_tx} x {n_rx} devices, "
               f"{len(pg)} links")
    order = np.lexsort((rid, tid))                                     # Tx-major rows
    tx, rx, tid, rid, pg = tx[order], rx[order], tid[order], rid[order], pg[order]
    channel = None if channel is None else channel[order]
    tx_dev = np.zeros((n_tx, 3))
    tx_dev[tid] = tx
    rx_dev = np.zeros((n_rx, 3))
    rx_dev[rid] = rx

    g_tx = rng["tx_gain"].normal(0.0, s.tx_gain_std_db, n_tx)
    g_rx = rng["rx_gain"].normal(0.0, s.rx_gain_std_db, n_rx)
    b_tx = random_directions(rng["tx_boresight"], n_tx)
    b_rx = random_directions(rng["rx_boresight"], n_rx)
    u = rx - tx
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pat = 10 * np.log10(pattern_gain(np.einsum("ij,ij->i", u, b_tx[tid]), s.pattern_exponent, s.pattern_floor)
                        * pattern_gain(-np.einsum("ij,ij->i", u, b_rx[rid]), s.pattern_exponent, s.pattern_floor))
    fading = rng["fading"].normal(0.0, s.fading_std_db, len(pg))
    delta = g_tx[tid] + g_rx[rid] + pat + fading
    out_db = pg + delta[:, None]
    say.append(f"device gains: N(0, {s.tx_gain_std_db:g} dB) per transmitter position, N(0, {s.rx_gain_std_db:g} dB) "
               f"per receiver (drawn: std {g_tx.std():.2f} / {g_rx.std():.2f} dB)")
    lo, hi = 10 * np.log10(pattern_gain(np.array([-1.0, 1.0]), s.pattern_exponent, s.pattern_floor))
    say.append(f"antenna patterns: (f + (1 - f) ((1 + cos psi) / 2)^q), q = {s.pattern_exponent:g}, f = "
               f"{s.pattern_floor:g}, {hi:+.1f} dBi front / {lo:+.1f} dBi back, each device's boresight uniform on "
               f"the sphere, applied toward the other end (link pattern terms: std {pat.std():.2f} dB)")
    say.append(f"fading: log-normal, N(0, {s.fading_std_db:g} dB) per link (drawn: std {fading.std():.2f} dB)")
    fields_out = {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.asarray(data["freq_hz"], np.float64),
                  "path_gain_db": out_db, "tx_id": tid.astype(np.int64), "rx_id": rid.astype(np.int64)}
    if channel is not None:     # the channel keeps its phase and gets the new magnitude (|h|^2 = path gain)
        mag = np.abs(channel)
        unit = np.where(mag > 0, channel / np.maximum(mag, 1e-300), 1.0 + 0j)
        fields_out["channel"] = unit * 10 ** (out_db / 20.0)
    if data.get("scene_bounds") is not None:
        fields_out["scene_bounds"] = np.asarray(data["scene_bounds"], np.float64)
    truth = {"seed": int(seed), "settings": asdict(s),
             "tx": {"pos_m": tx_dev.tolist(), "gain_db": g_tx.tolist(), "boresight": b_tx.tolist()},
             "rx": {"pos_m": rx_dev.tolist(), "gain_db": g_rx.tolist(), "boresight": b_rx.tolist()},
             "links": {"simulated_db": pg[:, 0].tolist(), "pattern_db": pat.tolist(), "fading_db": fading.tolist()}}
    return fields_out, truth, say


def run(sim_dir, out_dir, table: dict, seed: int = 0, config_toml: str = "", log=print) -> dict:
    """Read SIM_DIR/measurements.h5, write OUT_DIR (module docstring); returns {key: path written}."""
    from rfir_core.artifacts import read_artifact, write_artifact
    from rfir_core.provenance import Provenance

    started = time.time()
    s = parse_settings(table)
    src = Path(sim_dir) / "measurements.h5"
    if not src.exists():
        raise InputFileError("no measurements.h5 here: run `rfir simulate SCENE SIM_DIR` first", path=src)
    meas = read_artifact(src, "measurements")
    if str(meas.attrs.get("task", "")) != "rssi":
        raise InputFileError(f"task {meas.attrs.get('task')!r}: measured-like data are made from rssi", path=src)
    for key in ("tx_id", "rx_id"):
        if meas.get(key) is None:
            raise InputFileError(f"the rssi measurements have no {key}", path=src)
    try:
        spec = build_scene(str(meas.attrs["scene"]))
    except ValueError as exc:
        raise InputFileError(str(exc), path=src) from None
    plans = protocols(spec, s)
    rng = _streams(seed)
    v, f, fl, plan_names, offsets = floorplan_mesh(spec, rng["plan"], s.plan_error_std_m)
    data = {k: meas.get(k) for k in ("tx_pos", "rx_pos", "tx_id", "rx_id", "freq_hz", "path_gain_db", "channel",
                                     "scene_bounds")}
    fields_out, truth, say = transform(data, spec, s, seed)
    say.append(f"floor plan: {len(plan_names)} surfaces ({', '.join(plan_names)}), no furniture; interior walls "
               f"moved along their normal by N(0, {s.plan_error_std_m:g} m): "
               + ", ".join(f"{k} {v * 100:+.1f} cm" for k, v in offsets.items()))
    truth["floorplan"] = {"names": plan_names, "offsets_m": offsets, "source": dict(spec.info["floorplan"])}
    masks = {}
    for key, protocol in plans.items():
        train, test = protocol_masks(fields_out, protocol, str(src), seed)
        if not train.any() or not test.any():
            raise ConfigError(f"split {protocol!r} leaves no {'training' if not train.any() else 'test'} link")
        masks[key] = test
        say.append(f"split {key}: {protocol}: {describe(protocol)} ({int(test.sum())} test / {int(train.sum())} "
                   f"training links)")
    truth["splits"] = {k: {"protocol": p, "description": describe(p), "num_test": int(masks[k].sum())}
                       for k, p in plans.items()}
    for line in say:
        log(line)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    plan_dir = out / "floorplan"
    written["floorplan"] = write_ply(plan_dir / f"{spec.name}_floorplan.ply", v, f, None, fl)
    (plan_dir / "labels.json").write_text(json.dumps(
        {"scene": f"{spec.name} floor plan", "objects": [{"label": i, "name": n} for i, n in enumerate(plan_names)]},
        indent=1))
    sim_attrs = {k: v for k, v in meas.free.get("simulator@attrs", {}).items()}
    for key, protocol in plans.items():
        prov = Provenance(stage="simulate.measured_like", config_toml=config_toml)
        prov.add_input(src)
        prov.wall_time_s = time.time() - started
        prov.extra = {"seed": int(seed), "settings": asdict(s), "split_protocol": protocol, "applied": say}
        split = masks[key].astype(np.int64)
        attrs = {**sim_attrs, "measured_like": "; ".join(say), "measured_like.split_protocol": protocol,
                 "measured_like.seed": int(seed)}
        attrs = {k: (v if not isinstance(v, (list, tuple)) else np.asarray(v)) for k, v in attrs.items()}
        written[key] = write_artifact(out / PROTOCOL_FILES[key], "measurements", {**fields_out, "split": split},
                                      attrs={"task": "rssi", "scene": spec.name}, provenance=prov,
                                      free={"simulator": {"@attrs": attrs}})
    truth["assumptions"] = say
    truth["files"] = {k: Path(p).name for k, p in written.items()}
    (out / "truth.json").write_text(json.dumps(truth))
    written["truth"] = out / "truth.json"
    return written
