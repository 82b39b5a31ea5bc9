"""Typed settings of `rfir simulate`, parsed from the [simulate] config table."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from rfir_core.errors import ConfigError

from .measurement import MeasurementEffects
from .solve import PhysicsEffects

PATTERNS = ("directive", "lambertian", "backscattering")
BACKENDS = ("sionna", "po")


@dataclass(frozen=True)
class PoSettings:
    """Settings of the physical-optics backend (`rfir_stages.po.po_scattered_field`), [simulate.po].

    None for the three lengths = the solver's automatic choice (see docs/po.md)."""

    near_field: bool = True
    second_order: bool = True
    max_bounces: int = 3
    polarization: str = "V"
    shadow_samples: int = 4
    use_thickness: bool = True
    max_facet_edge_m: float | None = None
    shadow_refine_m: float | None = None
    sbr_spacing_m: float | None = None

    def __post_init__(self):
        if self.max_bounces < 2:   # read as "simulate: bad setting (...)" by parse_settings
            raise ValueError(f"po.max_bounces must be >= 2, got {self.max_bounces} (second_order = false: first order only)")

    def solver_kwargs(self) -> dict:
        return dict(near_field=bool(self.near_field), second_order=bool(self.second_order),
                    max_bounces=int(self.max_bounces),
                    polarization=str(self.polarization), shadow_samples=int(self.shadow_samples),
                    max_facet_edge_m=self.max_facet_edge_m, shadow_refine_m=self.shadow_refine_m,
                    sbr_spacing_m=self.sbr_spacing_m)


def _auto_len(v):
    if v is None or (isinstance(v, str) and v.lower() == "auto"):
        return None
    return float(v)


@dataclass
class SimulateSettings:
    tasks: list[str] = field(default_factory=lambda: ["auto"])
    quick: bool = False
    seed: int = 0
    scene_edits: list[str] = field(default_factory=list)  # stages/simulate/scene_edits.py
    photos: bool = True
    num_views: int = 0
    image_width: int = 640
    image_height: int = 480
    physics: PhysicsEffects = field(default_factory=PhysicsEffects)
    physics_scattering_coefficient: float = 0.3
    scattering_pattern: str = "directive"
    alpha_r: int = 4
    measurement: MeasurementEffects = field(default_factory=MeasurementEffects)
    rcs_freqs_hz: list[float] = field(default_factory=lambda: [2.4e9, 5.8e9])
    ranges_m: list[float] = field(default_factory=lambda: [2.0, 2.5, 3.0, 4.0, 4.5, 5.0])
    aspect_step_deg: float = 1.0
    horn_hpbw_deg: float = 40.0
    separation_m: float = 0.002
    rcs_samples_per_src: int = 30000
    rcs_max_paths: int = 200000
    focused_sampling: bool = True
    wideband_centre_hz: float = 5.8e9
    wideband_bandwidth_hz: float = 160e6
    wideband_num_freqs: int = 2000
    wideband_num_anchors: int = 5
    wideband_range_m: float = 3.0
    wideband_aspect_step_deg: float = 1.0
    rssi_freqs_hz: list[float] = field(default_factory=lambda: [2.4e9])
    # channels whose powers each rssi link averages (a survey over several channels); empty: one frequency
    rssi_channels_hz: list[float] = field(default_factory=list)
    # Sionna RT's pattern of every rssi antenna, V-polarised (RSSI_ANTENNAS); the measurements state it
    rssi_antenna: str = "iso"
    tx_grid: list[int] = field(default_factory=lambda: [6, 4])
    rx_grid: list[int] = field(default_factory=lambda: [22, 20])
    tx_height_m: float = 2.2
    rx_height_m: float = 1.0
    tx_margin_m: float = 1.0
    rx_margin_m: float = 0.4
    clearance_m: float = 0.05
    test_fraction: float = 0.2
    rssi_samples_per_src: int = 30000
    rssi_max_paths: int = 10_000_000
    rcs_backend: str = "sionna"
    po: PoSettings = field(default_factory=PoSettings)
    workers: int = 2
    worker_timeout_s: float = 900.0

    def physics_for(self, task: str) -> PhysicsEffects:
        if task == "rssi":
            return dataclasses.replace(self.physics, samples_per_src=self.rssi_samples_per_src,
                                       max_num_paths_per_src=self.rssi_max_paths)
        return dataclasses.replace(self.physics, samples_per_src=self.rcs_samples_per_src,
                                   max_num_paths_per_src=self.rcs_max_paths)

    def material_effects(self):
        from .radio_scene import MaterialEffects

        return MaterialEffects(self.physics_scattering_coefficient if self.physics.diffuse else 0.0,
                               self.scattering_pattern, self.alpha_r)

    def effects_dict(self, backend: str = "sionna") -> dict:
        """Every effect switch, for provenance and the simulator/ group.

        backend "po": the PO solver's settings replace Sionna's physics switches."""
        if backend == "po":
            return {"rcs_backend": "po", "po": {k: ("auto" if v is None else v)
                                                for k, v in dataclasses.asdict(self.po).items()},
                    "measurement": dataclasses.asdict(self.measurement)}
        p = self.physics
        return {
            "physics": {"max_depth": p.max_depth, "specular": p.specular, "refraction": p.refraction,
                        "diffraction": p.diffraction, "diffuse": p.diffuse,
                        "scattering_coefficient": self.physics_scattering_coefficient if p.diffuse else 0.0,
                        "scattering_pattern": self.scattering_pattern, "alpha_r": self.alpha_r,
                        "combine": p.combine, "sionna_seed": p.seed},
            "measurement": dataclasses.asdict(self.measurement),
        }


def _defaults() -> dict:
    from rfir_core.config import load_defaults

    return load_defaults().get("simulate", {})


# simulate.rssi.antenna: Sionna RT's pattern name -> how the measurements state it (docs/artifacts.md)
RSSI_ANTENNAS = {"iso": "isotropic", "dipole": "dipole:0,0,1"}
RSSI_KEYS = {"antenna", "freqs_hz", "channels_hz", "tx_grid", "rx_grid", "tx_height_m", "rx_height_m", "tx_margin_m",
             "rx_margin_m", "clearance_m",
             "test_fraction", "samples_per_src", "max_num_paths_per_src"}


def _scene_rssi(rs: dict, scene: str | None) -> dict:
    """The [simulate.rssi] table with [simulate.rssi.scenes.<scene>] laid over it (a scene's own grids)."""
    rs = dict(rs)
    per_scene = rs.pop("scenes", {}) or {}
    own = per_scene.get(scene, {}) if scene else {}
    unknown = sorted(set(own) - RSSI_KEYS)
    if unknown:
        raise ConfigError(f"simulate.rssi.scenes.{scene}: unknown key(s) {', '.join(unknown)}")
    return {**rs, **own}


def parse_settings(config: dict | None, quick: bool | None = None, scene: str | None = None) -> SimulateSettings:
    """Build settings from the [simulate] table; quick=True applies [simulate.quick_sizes]; scene: apply
    that scene's [simulate.rssi.scenes.<scene>] keys."""
    c = config if config is not None else _defaults()
    try:
        ph, me = c.get("physics", {}), c.get("measurement", {})
        rc, wb, qk = c.get("rcs", {}), c.get("wideband", {}), c.get("quick_sizes", {})
        rs = _scene_rssi(c.get("rssi", {}), scene)
        po = c.get("po", {})
        tasks = c.get("tasks", "auto")
        s = SimulateSettings(
            tasks=[tasks] if isinstance(tasks, str) else list(tasks),
            quick=bool(c.get("quick", False) if quick is None else quick),
            seed=int(c.get("seed", 0)), scene_edits=[str(e) for e in c.get("scene_edits", [])],
            photos=bool(c.get("photos", True)),
            num_views=int(c.get("num_views", 0)), image_width=int(c.get("image_width", 640)),
            image_height=int(c.get("image_height", 480)),
            physics=PhysicsEffects(max_depth=int(ph.get("max_depth", 3)), specular=bool(ph.get("specular", True)),
                                   diffuse=bool(ph.get("diffuse", True)), refraction=bool(ph.get("refraction", True)),
                                   diffraction=bool(ph.get("diffraction", False)),
                                   combine=str(ph.get("combine", "power")), seed=int(ph.get("sionna_seed", 7))),
            physics_scattering_coefficient=float(ph.get("scattering_coefficient", 0.3)),
            scattering_pattern=str(ph.get("scattering_pattern", "directive")), alpha_r=int(ph.get("alpha_r", 4)),
            measurement=MeasurementEffects(**{k: float(v) for k, v in me.items()}),
            rcs_freqs_hz=[float(f) for f in rc.get("freqs_hz", [2.4e9, 5.8e9])],
            ranges_m=[float(r) for r in rc.get("ranges_m", [2.0, 2.5, 3.0, 4.0, 4.5, 5.0])],
            aspect_step_deg=float(rc.get("aspect_step_deg", 1.0)), horn_hpbw_deg=float(rc.get("horn_hpbw_deg", 40.0)),
            separation_m=float(rc.get("separation_m", 0.002)),
            rcs_samples_per_src=int(rc.get("samples_per_src", 30000)),
            rcs_max_paths=int(rc.get("max_num_paths_per_src", 200000)),
            focused_sampling=bool(rc.get("focused_sampling", True)),
            wideband_centre_hz=float(wb.get("centre_hz", 5.8e9)), wideband_bandwidth_hz=float(wb.get("bandwidth_hz", 160e6)),
            wideband_num_freqs=int(wb.get("num_freqs", 2000)), wideband_num_anchors=int(wb.get("num_anchors", 5)),
            wideband_range_m=float(wb.get("range_m", 3.0)),
            wideband_aspect_step_deg=float(wb.get("aspect_step_deg", 1.0)),
            rssi_freqs_hz=[float(f) for f in rs.get("freqs_hz", [2.4e9])],
            rssi_channels_hz=[float(f) for f in rs.get("channels_hz", [])],
            rssi_antenna=str(rs.get("antenna", "iso")),
            tx_grid=[int(v) for v in rs.get("tx_grid", [6, 4])], rx_grid=[int(v) for v in rs.get("rx_grid", [22, 20])],
            tx_height_m=float(rs.get("tx_height_m", 2.2)), rx_height_m=float(rs.get("rx_height_m", 1.0)),
            tx_margin_m=float(rs.get("tx_margin_m", 1.0)), rx_margin_m=float(rs.get("rx_margin_m", 0.4)),
            clearance_m=float(rs.get("clearance_m", 0.05)),
            test_fraction=float(rs.get("test_fraction", 0.2)),
            rssi_samples_per_src=int(rs.get("samples_per_src", 30000)),
            rssi_max_paths=int(rs.get("max_num_paths_per_src", SimulateSettings.rssi_max_paths)),
            rcs_backend=str(c.get("rcs_backend", "sionna")).lower(),
            po=PoSettings(near_field=bool(po.get("near_field", True)), second_order=bool(po.get("second_order", True)),
                          max_bounces=int(po.get("max_bounces", 3)),
                          polarization=str(po.get("polarization", "V")).upper(),
                          shadow_samples=int(po.get("shadow_samples", 4)),
                          use_thickness=bool(po.get("use_thickness", True)),
                          max_facet_edge_m=_auto_len(po.get("max_facet_edge_m", "auto")),
                          shadow_refine_m=_auto_len(po.get("shadow_refine_m", "auto")),
                          sbr_spacing_m=_auto_len(po.get("sbr_spacing_m", "auto"))),
            workers=int(c.get("workers", 2)), worker_timeout_s=float(c.get("worker_timeout_s", 900.0)),
        )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"simulate: bad setting ({exc})") from None
    if s.quick:
        s.aspect_step_deg = s.wideband_aspect_step_deg = float(qk.get("aspect_step_deg", 30.0))
        s.ranges_m = [float(r) for r in qk.get("ranges_m", [3.0])]
        s.wideband_num_freqs = int(qk.get("wideband_num_freqs", 64))
        s.wideband_num_anchors = int(qk.get("wideband_num_anchors", 2))
        s.tx_grid = [int(v) for v in qk.get("tx_grid", [2, 1])]
        s.rx_grid = [int(v) for v in qk.get("rx_grid", [5, 4])]
        s.num_views = int(qk.get("num_views", 6))
        s.image_width = int(qk.get("image_width", 160))
        s.image_height = int(qk.get("image_height", 120))
        s.rcs_samples_per_src = s.rssi_samples_per_src = int(qk.get("samples_per_src", 10000))
    _validate(s)
    return s


def _validate(s: SimulateSettings) -> None:
    def bad(msg):
        raise ConfigError(f"simulate: {msg}")

    if s.physics.max_depth < 0:
        bad("physics.max_depth must be >= 0")
    if not 0.0 <= s.physics_scattering_coefficient <= 1.0:
        bad("physics.scattering_coefficient must be in [0, 1]")
    if s.scattering_pattern not in PATTERNS:
        bad(f"physics.scattering_pattern must be one of {', '.join(PATTERNS)}")
    if s.alpha_r < 1:
        bad("physics.alpha_r must be an integer >= 1")
    if s.physics.combine not in ("power", "coherent"):
        bad("physics.combine must be 'power' or 'coherent'")
    if s.aspect_step_deg <= 0 or s.wideband_aspect_step_deg <= 0:
        bad("aspect_step_deg must be > 0")
    if not s.ranges_m or min(s.ranges_m) <= 0:
        bad("rcs.ranges_m must be positive")
    if not s.rcs_freqs_hz or min(s.rcs_freqs_hz + s.rssi_freqs_hz) <= 0:
        bad("frequencies must be positive")
    if not 0.0 < s.horn_hpbw_deg < 180.0:
        bad("rcs.horn_hpbw_deg must be in (0, 180)")
    if s.rssi_antenna not in RSSI_ANTENNAS:
        bad(f"rssi.antenna = {s.rssi_antenna!r}: expected one of {', '.join(RSSI_ANTENNAS)}")
    if len(s.tx_grid) != 2 or len(s.rx_grid) != 2 or min(s.tx_grid + s.rx_grid) < 1:
        bad("rssi.tx_grid and rssi.rx_grid must be two positive integers")
    if not 0.0 <= s.test_fraction < 1.0:
        bad("rssi.test_fraction must be in [0, 1)")
    if s.clearance_m < 0:
        bad("rssi.clearance_m must be >= 0")
    if s.rssi_channels_hz and (len(s.rssi_freqs_hz) != 1 or min(s.rssi_channels_hz) <= 0):
        bad("rssi.channels_hz: positive frequencies, averaged about the one rssi.freqs_hz they are solved at")
    if s.wideband_num_freqs < 1 or s.wideband_num_anchors < 1:
        bad("wideband.num_freqs and num_anchors must be >= 1")
    if s.measurement.noise_db < 0:
        bad("measurement.noise_db must be >= 0")
    if s.rcs_backend not in BACKENDS:
        bad(f"rcs_backend must be one of {', '.join(BACKENDS)}, got {s.rcs_backend!r}")
    if s.po.polarization not in ("V", "H", "VH", "HV"):
        bad("po.polarization must be V, H, VH or HV")
    if s.po.shadow_samples not in (1, 4):
        bad("po.shadow_samples must be 1 or 4")
    if s.workers < 1:
        bad("workers must be >= 1 (1 = in-process)")
    if s.worker_timeout_s <= 0:
        bad("worker_timeout_s must be > 0")
    for t in s.tasks:
        if t != "auto" and t not in ("rssi", "rcs", "wideband"):
            bad(f"unknown task {t!r} (known: auto, rssi, rcs, wideband)")
