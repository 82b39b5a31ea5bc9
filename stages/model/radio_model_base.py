"""The radio-model interface: what every fitted model kind offers its callers (radio_model.py loads one).

A `RadioModel` is a fitted `rf` artifact loaded once and ready to predict: its geometry (the Gaussians),
its materials, its settings, and `predict(tx, rx, freqs)`, the path gain of links in dB. Every caller
(predict, edit, diagnose, the Python API) uses this interface and never asks which kind it holds; a kind
(the object RCS model, predict.py; the room model, room_radio_model.py) implements `_path_gain_db` and
says what its settings are. Units: positions in metres, frequencies in hertz, path gain
10 log10(P_received / P_transmitted) in dB with the fitted antennas, floored at FLOOR_DB.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from rfir_core.artifacts import check_output, write_artifact
from rfir_core.errors import ConfigError, StageError
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance

from .artifact import load_physical
from .links import geometry_from_artifact
from .occlusion import FrozenGeometry

# Predicted power below this (links that see no lit surfel: a plate edge-on) is reported at it, never -inf.
FLOOR_DB = -250.0


def link_positions(tx_m, rx_m) -> tuple[np.ndarray, np.ndarray]:
    """tx_m, rx_m as float64 [N, 3] m; one position [3] stands for N links from (or to) it. ConfigError
    (one line) for other shapes or non-finite values."""
    tx, rx = np.asarray(tx_m, np.float64), np.asarray(rx_m, np.float64)
    if tx.ndim == 1:
        tx = np.broadcast_to(tx, rx.shape if rx.ndim == 2 else (1, 3))
    if rx.ndim == 1:
        rx = np.broadcast_to(rx, tx.shape)
    if tx.ndim != 2 or tx.shape[1:] != (3,) or tx.shape != rx.shape:
        raise ConfigError(f"links: transmitters and receivers must be [N, 3] positions in metres, got {tx.shape} "
                          f"and {rx.shape}")
    if not (np.isfinite(tx).all() and np.isfinite(rx).all()):
        raise ConfigError("links: positions must be finite numbers (metres)")
    return np.ascontiguousarray(tx), np.ascontiguousarray(rx)


class RadioModel:
    """A fitted radio model (an `rf` artifact), loaded once. Build it with `radio_model.load_model`.

    Attributes every kind has:
    - kind: the registered name of its kind ("rcs_physical", "rssi_physical", ...);
    - artifact: the `rf` artifact it was loaded from (rfir_core.artifacts.Artifact); path: its file (None for
      an artifact built in memory);
    - geometry: the Gaussians (FrozenGeometry: means [G, 3] m, log_scales [G, 3], rotations [G, 4], normals [G, 3]);
    - settings: the kind's settings dataclass as fitted (PairSettings for the object model, RoomSettings for
      the room model);
    - fitted_freqs_hz [F]: the frequencies the materials were fitted at;
    - task: the measurement task it was fitted on ("rcs", "wideband" or "rssi").
    """

    kind: str = ""
    # memory of one link being predicted (paths, pairs and their coefficients); kinds set their own
    BYTES_PER_LINK = 40_000

    def __init__(self, rf, occlusion: str = "auto"):
        self.artifact = rf
        self.path = Path(rf.path) if getattr(rf, "path", None) else None
        self.occlusion = occlusion
        self.task = str(rf.attrs.get("task", ""))
        self.fitted_freqs_hz = np.asarray(rf["rf/freq_hz"], np.float64)
        self.physical = load_physical(rf)
        self.geometry: FrozenGeometry = geometry_from_artifact(rf)
        self.settings = None

    # -- what callers use -------------------------------------------------------------------------------------
    def predict(self, tx_m, rx_m, freqs_hz=None, *, progress=None, advance: Callable[[int], None] | None = None,
                chunk_links: int | None = None, axes=None) -> np.ndarray:
        """Path gain [N, F] dB (10 log10 P_r / P_t with the fitted antennas, floored at FLOOR_DB) of the links
        tx_m -> rx_m ([N, 3] m each, or one of them [3]) at freqs_hz [F] Hz (default: default_freqs()).

        The fitted model itself: the corrections `rfir diagnose` records in an artifact are applied on top by
        its callers (rfir_stages.diagnose.apply.apply_recorded_effects; `rfir predict` and the Python API do).
        progress: an rfir_core.progress.Progress for log lines (and a bar unless `advance` is given);
        advance(n): called as links are done, for a caller that keeps its own bar; chunk_links: links
        evaluated at a time (memory); axes: the links' antenna axes (antenna_patterns.LinkAxes of the N links; the
        room model's, None: each end's own)."""
        return self.predict_with_physics_only(tx_m, rx_m, freqs_hz, progress=progress, advance=advance,
                                              chunk_links=chunk_links, physics_only=False, axes=axes)[0]

    def predict_with_physics_only(self, tx_m, rx_m, freqs_hz=None, *, progress=None, advance=None,
                                  chunk_links: int | None = None, physics_only: bool = True, axes=None):
        """(path gain [N, F] dB as `predict`, the same without the fitted residual on top), in one pass over the
        links; the second equals the first for a model without a residual. physics_only=False: (path gain, None)."""
        tx, rx = link_positions(tx_m, rx_m)
        freqs = self.default_freqs() if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, np.float64))
        if freqs.ndim != 1 or not freqs.size or not (np.isfinite(freqs).all() and (freqs > 0).all()):
            raise ConfigError(f"frequencies must be positive numbers in hertz, got {np.asarray(freqs_hz).tolist()}")
        # antenna axes per link: the room model's alone takes them (a kind without them is never given any)
        oriented = {} if axes is None else {"axes": axes}
        return self._path_gain_db(tx, rx, freqs, progress or NullProgress(), advance, chunk_links, physics_only,
                                  **oriented)

    def default_freqs(self, measured_hz=None) -> np.ndarray:
        """Frequencies [F] Hz predicted when none are asked for: the fitted ones (a band fit: its band); with
        measured_hz [K] Hz, those of the measured frequencies (within 1e-6 relative)."""
        want = self._wanted_freqs(measured_hz)
        if measured_hz is None:
            return want
        f = np.asarray(measured_hz, np.float64)
        return f[[bool(np.any(np.abs(want - x) <= 1e-6 * x)) for x in f]]

    def _wanted_freqs(self, measured_hz=None) -> np.ndarray:
        return self.fitted_freqs_hz.copy()

    def training_split(self, meas) -> np.ndarray | None:
        """Per row of the measurements `meas` [L]: 0 training, 1 test, -1 unused, as the fit split them (the
        rows `rfir predict` scores); None where the fit's split cannot be told from the file."""
        split = meas.get("split")
        return None if split is None else np.asarray(split, np.int64)

    def held_out_rows(self, meas) -> tuple[np.ndarray, np.ndarray, str]:
        """(test rows, training rows, how they were chosen in words) of the measurements `meas` as the fit split
        them (training_split); StageError (one line naming the file) when the file cannot tell."""
        split = self.training_split(meas)
        if split is None:
            raise StageError("the measurements have no 'split' to score against", path=meas.path)
        return np.flatnonzero(split == 1), np.flatnonzero(split == 0), "the file's split column (test rows: split == 1)"

    def materials(self) -> dict[str, dict]:
        """The fitted materials, name -> {"eps_r": relative permittivity, "sigma_1ghz_s_per_m": conductivity at
        1 GHz [S/m], "sigma_exponent": d in sigma(f) = sigma_1GHz (f / 1 GHz)^d, "thickness_m": slab thickness
        [m] (0: a half-space), "scattering": S in [0, 1) (the diffuse share of the field), "gaussians": how many
        Gaussians carry it, "gamma_normal_abs": |Gamma| at normal incidence at the first fitted frequency, and
        "gamma_normal_range": (low, high) of that |Gamma| that the training links allow (stored by rf-fit with
        rf_fit.physical.reflection_ranges; absent otherwise)}. Materials without a stored name are material_I."""
        mats, names = self.physical.mats, self.physical.names
        index = self.physical.material_of_gaussian.numpy()
        th = None if mats.thickness_m is None else mats.thickness_m.numpy()
        gamma = mats.normal_reflection(torch.as_tensor(self.fitted_freqs_hz[:1])).abs()[:, 0].numpy()
        span = self.artifact.get("material/gamma_normal_range")
        out = {}
        for i in range(len(mats.eps_r)):
            name = names[i] if i < len(names) else f"material_{i}"
            out[name] = {"eps_r": float(mats.eps_r[i]), "sigma_1ghz_s_per_m": float(mats.sigma_1ghz[i]),
                         "sigma_exponent": float(mats.sigma_exponent),
                         "thickness_m": 0.0 if th is None else float(th[i]),
                         "scattering": float(mats.scattering[i]), "gaussians": int(np.sum(index == i)),
                         "gamma_normal_abs": float(gamma[i])}
            if span is not None:
                out[name]["gamma_normal_range"] = (float(span[i][0]), float(span[i][1]))
        return out

    def memory_estimate_bytes(self, num_links: int, chunk_links: int) -> int:
        """Estimated memory [bytes] of predicting num_links links chunk_links at a time."""
        return int(min(num_links, chunk_links) * self.BYTES_PER_LINK + num_links * 200)

    @property
    def provider(self):
        """The occlusion provider of the Gaussians (rays -> hits; model/occlusion.py), built on first use."""
        if getattr(self, "_provider", None) is None:
            from .occlusion import make_provider

            self._provider = make_provider(self.occlusion, self.geometry)
        return self._provider

    def save(self, path) -> Path:
        """Write the model as an `rf` artifact at `path` (never over the file it was loaded from); returns path."""
        path = Path(path)
        inputs = [self.path] if self.path is not None else []
        check_output(path, "rf", inputs)
        rf = self.artifact
        prov = Provenance(stage="model.save")
        for p in inputs:
            prov.add_input(p)
        prov.extra = {"upstream": rf.provenance.stage, "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        return write_artifact(path, "rf", dict(rf.data), attrs=dict(rf.attrs), provenance=prov,
                              free=rf.free_for_write())

    def describe(self) -> str:
        """One line: kind, Gaussians, materials, fitted frequencies."""
        ghz = ", ".join(f"{f / 1e9:g}" for f in self.fitted_freqs_hz[:4]) + (" ..." if len(self.fitted_freqs_hz) > 4
                                                                          else "")
        return (f"{self.kind} model ({self.task} fit): {self.geometry.num} Gaussians, "
                f"{len(self.physical.mats.eps_r)} materials, fitted at {ghz} GHz")

    # -- what a kind implements ---------------------------------------------------------------------------------
    def _path_gain_db(self, tx: np.ndarray, rx: np.ndarray, freqs: np.ndarray, progress, advance, chunk_links,
                      physics_only: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """(path gain [N, F] dB, the same without a residual or None unless physics_only) for checked links."""
        raise NotImplementedError
