"""The rfir artifact schema: every kind, field, dtype, shape and unit, in one place.

An artifact is an HDF5 file. Root attributes: `kind`, `schema_version` (semver), `producer`,
`created`. Group `/provenance` records how it was made. Datasets sit at fixed paths
("group/name") and carry a `unit` attribute (and `frame` where spatial).

Shapes use symbolic dimensions (e.g. "L" links, "F" frequencies, "G" Gaussians); a symbol must
have the same size in every field of one file. Readers accept files of the same major version
(minor versions only add optional fields). See docs/artifacts.md for the user-facing description.

Change history
- 1.0.0 (2026-11-23): first release: measurements, cameras, calib, scene, rf, predictions.
- 1.1.0 (2026-11-25): optional measurement set-up attributes of `measurements` (antenna_tx,
  antenna_rx, their pattern tables, polarisation, power, tx_power_dbm).
- 1.2.0 (2026-11-25): optional residual/* fields of `rf` (the residual on top of the physical model).
- 1.4.0 (2026-11-26): optional residual/floor_db of `rf` (the floor under the physics of a kernel residual;
  read as none when absent).
- 1.5.0 (2026-11-26): optional root attribute edge_waves of `rf` (on / off: the model includes the edge
  waves of its planar patches; read as off when absent).
- 1.6.0 (2026-12-07): optional sample_count and sample_std_db of `measurements` (repeated rows of a
  link averaged on import; read as one sample, no spread, when absent).
- 1.7.0 (2026-12-07): optional tx_axis and rx_axis of `measurements` (each link's antenna axis or boresight;
  read as the antenna attribute's one axis when absent), and a horn's or table's boresight in its antenna text.
"""
from __future__ import annotations

from dataclasses import dataclass, field

SCHEMA_VERSION = "1.7.0"
SCHEMA_MAJOR = int(SCHEMA_VERSION.split(".")[0])


@dataclass(frozen=True)
class FieldSpec:
    """One dataset of an artifact kind.

    dtype: "float", "int", "complex", "uint8", "bool" or "str" (UTF-8).
    shape: tuple of int (fixed size) or str (symbolic dimension shared across the file).
    unit: SI unit or "1" for dimensionless, "dB"/"dBsm" at the edges; "" for labels and text.
    frame: "world" (z up, metres) or "camera" (OpenCV) for spatial quantities, else "".
    finite: NaN or Inf are refused (for float and complex fields).
    """

    name: str
    dtype: str
    shape: tuple
    unit: str
    doc: str
    required: bool = True
    frame: str = ""
    finite: bool = True


@dataclass(frozen=True)
class AttrSpec:
    """An optional root attribute of a kind.

    dtype: "str", "float" (a finite number) or "float[]" (a 1-D array of finite numbers).
    choices: allowed values of a "str" (empty: any); pattern: a regular expression a "str" must match.
    """

    name: str
    dtype: str
    doc: str
    choices: tuple = ()
    pattern: str = ""


_NUM = r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?"
ANTENNA_PATTERN = rf"isotropic|dipole(:{_NUM},{_NUM},{_NUM})?|horn:{_NUM}(@{_NUM},{_NUM},{_NUM})?|table:.+"


@dataclass(frozen=True)
class KindSpec:
    """An artifact kind: its fields, its required root attributes, and free-form groups."""

    kind: str
    doc: str
    fields: tuple[FieldSpec, ...]
    required_attrs: tuple[str, ...] = ()
    free_groups: tuple[str, ...] = field(default_factory=tuple)
    optional_attrs: tuple[AttrSpec, ...] = ()
    # (a required field, the problem to report instead when it is missing): a file of a retired model
    # family lacks that field, and the one line should say so rather than list missing datasets
    retired: tuple[str, str] | None = None

    def field(self, name: str) -> FieldSpec | None:
        return next((f for f in self.fields if f.name == name), None)


def F(name, dtype, shape, unit, doc, **kw) -> FieldSpec:
    return FieldSpec(name, dtype, tuple(shape), unit, doc, **kw)


_GAUSSIANS = (
    F("gaussians/means", "float", ("G", 3), "m", "Gaussian centres", frame="world"),
    F("gaussians/log_scales", "float", ("G", 3), "log(m)", "natural log of the standard deviations along the local axes"),
    F("gaussians/rotations", "float", ("G", 4), "1", "unit quaternions (w, x, y, z), local-to-world"),
    F("gaussians/opacities", "float", ("G",), "1", "visual opacity in [0, 1]"),
    F("gaussians/colors", "float", ("G", "C"), "1", "appearance: RGB in [0, 1] or SH coefficients", required=False),
    F("gaussians/normals", "float", ("G", 3), "1", "unit surface normals", frame="world"),
    F("gaussians/labels", "int", ("G",), "", "object label per Gaussian (-1: none); names in attr label_names", required=False),
)

KINDS: dict[str, KindSpec] = {}


def _register(spec: KindSpec) -> None:
    KINDS[spec.kind] = spec


_register(KindSpec(
    "measurements",
    "Radio measurements: one row per link (Tx, Rx pair), one column per frequency.",
    (
        F("tx_pos", "float", ("L", 3), "m", "transmitter positions", frame="world"),
        F("rx_pos", "float", ("L", 3), "m", "receiver positions", frame="world"),
        F("freq_hz", "float", ("F",), "Hz", "carrier frequencies"),
        F("path_gain_db", "float", ("L", "F"), "dB", "received / transmitted power, 10 log10"),
        F("channel", "complex", ("L", "F"), "1", "complex baseband channel (|h|^2 = path gain)", required=False),
        F("rcs_dbsm", "float", ("L", "F"), "dBsm", "monostatic radar cross section", required=False),
        F("aspect_rad", "float", ("L",), "rad", "turntable aspect angle of the object", required=False),
        F("range_m", "float", ("L",), "m", "radar-to-object-centre range", required=False),
        F("tx_id", "int", ("L",), "", "transmitter index", required=False),
        F("rx_id", "int", ("L",), "", "receiver index", required=False),
        F("split", "int", ("L",), "", "0 = train, 1 = test, -1 = unassigned", required=False),
        F("sample_count", "int", ("L",), "", "rows averaged into each link (import --average; the fewest of the "
          "link's frequencies when they differ); absent: one row each", required=False),
        F("sample_std_db", "float", ("L", "F"), "dB", "standard deviation (ddof 1) of the averaged rows' power_db per "
          "link and frequency (import --average; 0 for a single row)", required=False),
        F("tx_axis", "float", ("L", 3), "1", "transmit antenna's axis per link (a dipole's axis, a horn's or table's "
          "boresight; unit vector); replaces antenna_tx's axis for that link", required=False, frame="world"),
        F("rx_axis", "float", ("L", 3), "1", "receive antenna's axis per link, as tx_axis", required=False, frame="world"),
        F("scene_bounds", "float", (2, 3), "m", "axis-aligned bounds (min, max) of the scene", required=False, frame="world"),
    ),
    required_attrs=("task", "scene"),
    free_groups=("simulator",),
    optional_attrs=(
        AttrSpec("task", "str", "rcs (monostatic, one or a few discrete frequencies), wideband (a dense band) "
                 "or rssi (links between placed antennas)", choices=("rcs", "wideband", "rssi")),
        AttrSpec("antenna_tx", "str", "transmit antenna: isotropic, dipole:AX,AY,AZ (unit axis), horn:HPBW_DEG "
                 "(cos^q horn, half-power beamwidth) or table:NAME (pattern in antenna_tx_table_*), a horn's or "
                 "table's boresight after @AX,AY,AZ (absent: +z); absent: not stated (rf-fit assumes isotropic and "
                 "says so)", pattern=ANTENNA_PATTERN),
        AttrSpec("antenna_rx", "str", "receive antenna, as antenna_tx", pattern=ANTENNA_PATTERN),
        AttrSpec("antenna_tx_table_deg", "float[]", "table pattern: angle off boresight [deg], rising from 0"),
        AttrSpec("antenna_tx_table_gain_dbi", "float[]", "table pattern: gain [dBi] at each angle"),
        AttrSpec("antenna_rx_table_deg", "float[]", "as antenna_tx_table_deg, receive side"),
        AttrSpec("antenna_rx_table_gain_dbi", "float[]", "as antenna_tx_table_gain_dbi, receive side"),
        AttrSpec("polarisation", "str", "polarisation of both antennas (V: along z, H: horizontal)",
                 choices=("V", "H")),
        AttrSpec("power", "str", "what the imported power column held: path_gain [dB], rcs [dBsm, converted to "
                 "path gain by the radar equation with the antennas' boresight gains] or rssi [dBm, minus "
                 "tx_power_dbm]", choices=("path_gain", "rcs", "rssi")),
        AttrSpec("tx_power_dbm", "float", "transmit power [dBm] subtracted from the received power (power = rssi)"),
    ),
))

_register(KindSpec(
    "cameras",
    "Ground-truth or user-supplied camera intrinsics and poses for a folder of images.",
    (
        F("image_names", "str", ("N",), "", "file names relative to the images folder"),
        F("intrinsics", "float", ("N", 3, 3), "px", "pinhole camera matrices K"),
        F("world_from_camera", "float", ("N", 4, 4), "m", "camera-to-world rigid transforms (OpenCV camera axes)", frame="world"),
        F("image_size", "int", ("N", 2), "px", "width, height"),
    ),
    required_attrs=("scene",),
))

_register(KindSpec(
    "calib",
    "Camera calibration from structure from motion, aligned to metres in the scene frame.",
    (
        F("image_paths", "str", ("N",), "", "image paths (absolute, or relative to the artifact)"),
        F("image_sha256", "str", ("N",), "", "SHA-256 of each image file"),
        F("image_size", "int", ("N", 2), "px", "width, height (after undistortion)"),
        F("intrinsics", "float", ("N", 3, 3), "px", "pinhole camera matrices K"),
        F("world_from_camera", "float", ("N", 4, 4), "m", "camera-to-world rigid transforms (OpenCV axes)", frame="world"),
        F("reproj_error_px", "float", ("N",), "px", "mean reprojection error per image"),
        F("points_xyz", "float", ("P", 3), "m", "sparse SfM points", frame="world"),
        F("points_rgb", "uint8", ("P", 3), "", "point colours"),
        F("points_track_length", "int", ("P",), "", "number of images observing each point"),
        F("alignment_sim3", "float", (4, 4), "m", "similarity transform from SfM frame to world (scale in the rotation block)"),
        F("alignment_residuals_m", "float", ("A",), "m", "residuals of the metric alignment references", required=False),
    ),
    required_attrs=("metric",),
))

_register(KindSpec(
    "scene",
    "3D Gaussians with normals, fitted to calibrated photos (geometry only).",
    _GAUSSIANS,
    free_groups=("training",),
))

_register(KindSpec(
    "rf",
    "A scene with the physical radio model's materials fitted to measurements (docs/physics.md).",
    _GAUSSIANS + (
        F("rf/opacity", "float", ("G",), "1", "RF opacity a in [0, 1] of the traced visibility"),
        F("rf/roughness", "float", ("G",), "1", "lobe exponent (1: the physical model has none)"),
        F("rf/gamma_abs", "float", ("G",), "1", "|Gamma| at normal incidence of the Gaussian's material at the "
          "first fitted frequency (attribute maps)"),
        F("rf/gamma_phase_rad", "float", ("G",), "rad", "angle of that Gamma"),
        F("rf/freq_hz", "float", ("F",), "Hz", "frequencies the model was fitted at"),
        # the physical model (rfir_stages.model.artifact; docs/physics.md section 8), N materials
        F("material/index", "int", ("G",), "", "material of each Gaussian (0..N-1)"),
        F("material/area_m2", "float", ("G",), "m^2", "surfel area A_l"),
        F("material/eps_r", "float", ("N",), "1", "relative permittivity (real part)"),
        F("material/sigma_1ghz_s_per_m", "float", ("N",), "S/m", "conductivity at 1 GHz"),
        F("material/scattering", "float", ("N",), "1", "scattering coefficient S in [0, 1)"),
        F("material/thickness_m", "float", ("N",), "m", "slab thickness (0: half-space)"),
        F("material/gamma_normal_abs", "float", ("N", "F"), "1", "|Gamma| at normal incidence per fitted frequency"),
        F("material/gamma_normal_range", "float", ("N", 2), "1", "low, high |Gamma| at normal incidence (first fitted "
          "frequency) that the training links cannot tell apart from the fitted material", required=False),
        # the residual on top of the physical model (rfir_stages.model.residual), T training links
        F("residual/tx_pos", "float", ("T", 3), "m", "smooth / blend residual: transmitter of each training link",
          required=False, frame="world"),
        F("residual/rx_pos", "float", ("T", 3), "m", "smooth / blend residual: receiver of each training link",
          required=False, frame="world"),
        F("residual/weights_db", "float", ("T", "F"), "dB", "smooth / blend residual: (K + eta I)^-1 r per fitted "
          "frequency", required=False),
        F("residual/mean_db", "float", ("F",), "dB", "blend residual: mean measured path gain (0 for smooth)",
          required=False),
        F("residual/floor_db", "float", ("F",), "dB", "smooth / blend residual: floor under the physics the form "
          "was fitted on (30 dB below the weakest training row)", required=False),
        F("residual/surfel", "float", ("G", 2), "1", "gaussian residual: real, imaginary part of each surfel's "
          "factor r (its specular term times 1 + r)", required=False),
    ),
    required_attrs=("task",),
    free_groups=("model", "training", "effects"),
    optional_attrs=(
        AttrSpec("edge_waves", "str", "whether the model includes the fringe field of its planar patches' outer "
                 "edges (docs/physics.md section 8.13; chosen by validation when rf_fit.physical.edge_waves = "
                 "auto); absent: off", choices=("on", "off")),
    ),
    retired=("material/index", "an rf model of the retired per-Gaussian family (a free reflection coefficient "
                               "per Gaussian), which rfir no longer reads; re-run rf-fit"),
))

_register(KindSpec(
    "predictions",
    "Predicted radio quantities per link, optionally beside the measured ones.",
    (
        F("tx_pos", "float", ("L", 3), "m", "transmitter positions", frame="world"),
        F("rx_pos", "float", ("L", 3), "m", "receiver positions", frame="world"),
        F("freq_hz", "float", ("F",), "Hz", "frequencies"),
        F("path_gain_db", "float", ("L", "F"), "dB", "predicted path gain"),
        F("rcs_dbsm", "float", ("L", "F"), "dBsm", "predicted RCS", required=False),
        F("measured_db", "float", ("L", "F"), "dB", "measured value of the same quantity, when given", required=False),
        F("aspect_rad", "float", ("L",), "rad", "aspect angle", required=False),
        F("range_m", "float", ("L",), "m", "range", required=False),
        F("split", "int", ("L",), "", "0 train, 1 test, -1 unassigned", required=False),
    ),
    required_attrs=("task",),
    free_groups=("metrics",),
))


def get_kind(kind: str) -> KindSpec:
    """Return the spec of `kind`, raising KeyError with the known kinds listed."""
    if kind not in KINDS:
        raise KeyError(f"unknown artifact kind {kind!r} (known: {', '.join(sorted(KINDS))})")
    return KINDS[kind]
