"""Residual terms of the room model, linear in dB (docs/physics.md section 8.15): what real surveys have and a
floor plan's physics lacks, fitted after the physical fit to its training residuals r = measured - physical [dB].

    P_dB(link) = P_physical_dB(link) + a_d . f(u) - sum_c W[link, c] x_c + k_d(x)

- Device patterns a_d . f(u): per fixed device d (one position, many links: an anchor), a low-order expansion
  f(u) = (cos az, sin az, cos 2 az, sin 2 az, sin el) of the direction u from d to the link's other end along the
  direct line (azimuth az from +x, elevation el above the horizontal). The direct line, not the power-weighted
  directions of the fitted paths: it needs no paths at prediction and carries the same low orders where the
  direct and nearby paths carry most of the power. No constant term: a device's offset is its device gain (8.11).
- Clutter field x [C] dB/m: the excess loss per metre of a link's tx-rx segment in each floor cell c (a vertical
  column cell_m x cell_m over the floor plan; what furniture and people missing from the plan take away).
  W[link, c] is the segment's 3D length inside column c in metres, by midpoint samples every cell_m / 10 along it.
  Only cells some training link crosses are unknowns: the others stay at the prior, 0.
- Kriging k_d(x): per fixed device, the mean of a zero-mean Gaussian process over the position x of the link's
  other end (the roaming device), exponential kernel s^2 exp(-|x - x'| / length), fitted to what the patterns and
  the field leave; it reverts to 0 (physics alone) farther than a few lengths from every training position.

A fixed device is matched at prediction by its position (1 mm, as device_gains.gains_at); a device the fit did
not see gets no pattern and no kriging, and the field applies to every link. Fitting: fit_linear (ridge + grid
smoothness), fit_kriging; which terms and their hyper-parameters: rfir_stages.rf_fit.residual_choice.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .device_gains import KEY_DECIMALS

TERMS = ("patterns", "field", "kriging")
NUM_PATTERN = 5             # cos az, sin az, cos 2az, sin 2az, sin el
SAMPLES_PER_CELL = 10       # midpoint samples per cell width along a segment (W to about 5 %)
CHUNK_LINKS = 4096          # links evaluated at a time (memory of the field's samples and the kernel rows)
PREFIX = "residual_terms_"  # the model group's fields (artifact)


def pattern_features(fixed_m: np.ndarray, other_m: np.ndarray) -> np.ndarray:
    """f(u) [N, 5] of the directions from fixed_m to other_m [N, 3] m (module docstring)."""
    d = np.asarray(other_m, np.float64) - np.asarray(fixed_m, np.float64)
    az = np.arctan2(d[:, 1], d[:, 0])
    el = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    return np.stack([np.cos(az), np.sin(az), np.cos(2 * az), np.sin(2 * az), np.sin(el)], axis=1)


@dataclass
class FloorGrid:
    """Cells of cell_m [m] over the floor: cell (i, j) spans x in origin_x + [i, i+1) cell_m, y likewise;
    shape (nx, ny); a cell's flat index is i * ny + j."""

    origin_m: np.ndarray
    cell_m: float
    shape: tuple

    @classmethod
    def covering(cls, lo_xy, hi_xy, cell_m: float) -> "FloorGrid":
        """The grid of cell_m cells over the rectangle lo_xy .. hi_xy [2] m."""
        lo, hi = np.asarray(lo_xy, np.float64), np.asarray(hi_xy, np.float64)
        n = np.maximum(1, np.ceil((hi - lo) / cell_m - 1e-9).astype(int))
        return cls(lo, float(cell_m), (int(n[0]), int(n[1])))

    @property
    def num(self) -> int:
        return self.shape[0] * self.shape[1]

    def centres(self) -> np.ndarray:
        """Centre of each cell [C, 2] m, in flat order."""
        i, j = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        return self.origin_m + (np.stack([i.ravel(), j.ravel()], 1) + 0.5) * self.cell_m

    def neighbours(self) -> np.ndarray:
        """[P, 2] flat indices of the edge-adjacent cell pairs."""
        idx = np.arange(self.num).reshape(self.shape)
        return np.concatenate([np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1),
                               np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)])

    def lengths(self, tx_m: np.ndarray, rx_m: np.ndarray):
        """W: scipy.sparse CSR [N, C], the 3D length [m] of each link's tx-rx segment inside each cell's column
        (midpoint samples every cell_m / SAMPLES_PER_CELL or closer); parts outside the grid count nowhere."""
        from scipy.sparse import coo_matrix, vstack

        tx, rx = np.asarray(tx_m, np.float64).reshape(-1, 3), np.asarray(rx_m, np.float64).reshape(-1, 3)
        blocks = []
        for lo in range(0, max(len(tx), 1), CHUNK_LINKS):
            a, b = tx[lo:lo + CHUNK_LINKS], rx[lo:lo + CHUNK_LINKS]
            d = b - a
            flat = np.hypot(d[:, 0], d[:, 1])
            num = int(np.ceil(flat.max(initial=0.0) * SAMPLES_PER_CELL / self.cell_m)) + 1
            t = (np.arange(num) + 0.5) / num
            xy = a[:, None, :2] + t[None, :, None] * d[:, None, :2]
            cell = np.floor((xy - self.origin_m) / self.cell_m).astype(np.int64)
            inside = ((cell >= 0) & (cell < np.asarray(self.shape))).all(-1)
            rows = np.broadcast_to(np.arange(len(a))[:, None], inside.shape)[inside]
            cols = cell[inside][:, 0] * self.shape[1] + cell[inside][:, 1]
            vals = np.broadcast_to((np.linalg.norm(d, axis=1) / num)[:, None], inside.shape)[inside]
            blocks.append(coo_matrix((vals, (rows, cols)), shape=(len(a), self.num)).tocsr())
        return vstack(blocks).tocsr() if blocks else coo_matrix((0, self.num)).tocsr()


def device_keys(points_m: np.ndarray) -> np.ndarray:
    """Positions [N, 3] rounded to 1 mm, as device_gains keys devices."""
    return np.round(np.asarray(points_m, np.float64).reshape(-1, 3), KEY_DECIMALS)


def match_devices(device_pos_m: np.ndarray, points_m: np.ndarray) -> np.ndarray:
    """[N] index into device_pos_m [D, 3] of each point [N, 3] at a device's position (1 mm), -1 elsewhere."""
    lookup = {tuple(p): d for d, p in enumerate(device_keys(device_pos_m))}
    return np.asarray([lookup.get(tuple(k), -1) for k in device_keys(points_m)], np.int64)


def exponential_kernel(a_m: np.ndarray, b_m: np.ndarray, length_m: float) -> np.ndarray:
    """exp(-|a - b| / length) [A, B] of points a_m [A, 3], b_m [B, 3] m."""
    d2 = (a_m ** 2).sum(1)[:, None] + (b_m ** 2).sum(1)[None, :] - 2 * a_m @ b_m.T
    return np.exp(-np.sqrt(np.maximum(d2, 0.0)) / length_m)


@dataclass
class ResidualTerms:
    """Fitted residual terms (module docstring). side: the fixed devices' side ("tx" or "rx"); device_pos_m [D, 3];
    pattern [D, 5] dB (None: no patterns); grid and field_db_per_m [C] (None: no field); kriging_device [T] int,
    kriging_pos_m [T, 3] m (the other ends of the training links), kriging_weight_db [T] (s^2 alpha: the kriged
    residual is sum_t exp(-|x - x_t| / length) w_t over the device's t), kriging_length_m (None: no kriging)."""

    side: str
    device_pos_m: np.ndarray
    pattern: np.ndarray | None = None
    grid: FloorGrid | None = None
    field_db_per_m: np.ndarray | None = None
    kriging_device: np.ndarray | None = None
    kriging_pos_m: np.ndarray | None = None
    kriging_weight_db: np.ndarray | None = None
    kriging_length_m: float | None = None

    @property
    def which(self) -> list[str]:
        return [n for n, on in zip(TERMS, (self.pattern is not None, self.field_db_per_m is not None,
                                           self.kriging_length_m is not None)) if on]

    def ends(self, tx_m, rx_m) -> tuple[np.ndarray, np.ndarray]:
        """(fixed end, other end) [N, 3] m of links tx_m, rx_m."""
        tx, rx = np.asarray(tx_m, np.float64).reshape(-1, 3), np.asarray(rx_m, np.float64).reshape(-1, 3)
        return (rx, tx) if self.side == "rx" else (tx, rx)

    def apply_db(self, tx_m, rx_m) -> np.ndarray:
        """The terms' sum [N] dB for links tx_m, rx_m [N, 3] m."""
        fixed, other = self.ends(tx_m, rx_m)
        out = np.zeros(len(fixed))
        if not self.which:
            return out
        device = match_devices(self.device_pos_m, fixed)
        seen = device >= 0
        if self.pattern is not None and seen.any():
            out[seen] += (pattern_features(fixed[seen], other[seen]) * self.pattern[device[seen]]).sum(1)
        if self.field_db_per_m is not None:
            out -= self.grid.lengths(fixed, other) @ self.field_db_per_m
        if self.kriging_length_m is not None:
            for d in np.unique(device[seen]):
                mine = np.flatnonzero(self.kriging_device == d)
                rows = np.flatnonzero(device == d)
                for lo in range(0, len(rows), CHUNK_LINKS):
                    r = rows[lo:lo + CHUNK_LINKS]
                    out[r] += exponential_kernel(other[r], self.kriging_pos_m[mine], self.kriging_length_m) \
                        @ self.kriging_weight_db[mine]
        return out

    def describe(self) -> str:
        """One line: the terms and their sizes."""
        if not self.which:
            return "off"
        words = []
        if self.pattern is not None:
            words.append(f"patterns ({len(self.device_pos_m)} {self.side} devices, |a| up to "
                         f"{np.abs(self.pattern).max():.1f} dB)")
        if self.field_db_per_m is not None:
            crossed = int((self.field_db_per_m != 0).sum())
            words.append(f"field ({self.grid.cell_m:g} m cells, {crossed} crossed, {self.field_db_per_m.min():+.2f} .. "
                         f"{self.field_db_per_m.max():+.2f} dB/m)")
        if self.kriging_length_m is not None:
            words.append(f"kriging (exponential, length {self.kriging_length_m:g} m, {len(self.kriging_pos_m)} points)")
        return " + ".join(words)

    # -- the artifact ------------------------------------------------------------------------------------------
    def table(self) -> dict:
        """Fields of the model group (PREFIX + name) for the terms that are on."""
        out = {PREFIX + "device_pos_m": np.asarray(self.device_pos_m, np.float64)}
        if self.pattern is not None:
            out[PREFIX + "pattern_db"] = np.asarray(self.pattern, np.float64)
        if self.field_db_per_m is not None:
            out[PREFIX + "field_db_per_m"] = np.asarray(self.field_db_per_m, np.float64).reshape(self.grid.shape)
            out[PREFIX + "grid_origin_m"] = np.asarray(self.grid.origin_m, np.float64)
        if self.kriging_length_m is not None:
            out[PREFIX + "kriging_device"] = np.asarray(self.kriging_device, np.int64)
            out[PREFIX + "kriging_pos_m"] = np.asarray(self.kriging_pos_m, np.float64)
            out[PREFIX + "kriging_weight_db"] = np.asarray(self.kriging_weight_db, np.float64)
        return out

    def attrs(self) -> dict:
        """Attributes of the model group: residual_terms (the terms joined by " + ", or "off") and their settings."""
        out = {"residual_terms": " + ".join(self.which) or "off", "residual_terms.side": self.side}
        if self.grid is not None and self.field_db_per_m is not None:
            out["residual_terms.cell_m"] = float(self.grid.cell_m)
        if self.kriging_length_m is not None:
            out["residual_terms.kriging_length_m"] = float(self.kriging_length_m)
        return out

    @classmethod
    def from_model(cls, stored: dict, attrs: dict) -> "ResidualTerms | None":
        """The terms stored in an rf artifact's model group (stored: its fields, attrs: its attributes); None for
        a model without them."""
        if str(attrs.get("residual_terms", "off")) == "off" or PREFIX + "device_pos_m" not in stored:
            return None
        get = lambda k: None if PREFIX + k not in stored else np.asarray(stored[PREFIX + k])  # noqa: E731
        grid = values = None
        if get("field_db_per_m") is not None:
            values = get("field_db_per_m").astype(np.float64)
            grid = FloorGrid(get("grid_origin_m").astype(np.float64), float(attrs["residual_terms.cell_m"]),
                             tuple(int(n) for n in values.shape))
            values = values.reshape(-1)
        length = attrs.get("residual_terms.kriging_length_m")
        return cls(str(attrs.get("residual_terms.side", "rx")), get("device_pos_m").astype(np.float64),
                   get("pattern_db"), grid, values, get("kriging_device"), get("kriging_pos_m"),
                   get("kriging_weight_db"), None if length is None else float(length))


# -- fitting ---------------------------------------------------------------------------------------------------
def laplacian(grid: FloorGrid, active: np.ndarray):
    """The graph Laplacian [A, A] (scipy.sparse) of the active cells (flat indices [A]) over their edge-adjacent
    pairs: x^T L x = sum over adjacent active pairs (x_i - x_j)^2."""
    from scipy.sparse import coo_matrix, diags

    where = np.full(grid.num, -1)
    where[active] = np.arange(len(active))
    pairs = where[grid.neighbours()]
    pairs = pairs[(pairs >= 0).all(1)]
    n = len(active)
    adj = coo_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])),
                     shape=(n, n)).tocsr()
    return diags(np.asarray(adj.sum(1)).ravel()) - adj


def pattern_design(device: np.ndarray, features: np.ndarray, num_devices: int):
    """P [N, 5 D] (scipy.sparse): each link's features in its device's block (device -1: an empty row)."""
    from scipy.sparse import coo_matrix

    rows = np.flatnonzero(device >= 0)
    cols = device[rows][:, None] * NUM_PATTERN + np.arange(NUM_PATTERN)
    return coo_matrix((features[rows].ravel(), (np.repeat(rows, NUM_PATTERN), cols.ravel())),
                      shape=(len(device), NUM_PATTERN * num_devices)).tocsr()


def fit_linear(residual_db: np.ndarray, pattern_rows=None, lengths=None, grid: FloorGrid | None = None,
               pattern_prior_db: float = 2.0, field_prior_db_per_m: float = 1.0, smooth_prior_db_per_m: float = 0.3
               ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(pattern coefficients [5 D] dB or None, field [C] dB/m or None) minimising, with s^2 = mean r^2,

        sum_links (r - P a + W x)^2 + s^2 (|a|^2 / pa^2 + |x|^2 / px^2 + x^T L x / ps^2),

    residual_db r [M]; pattern_rows P [M, 5 D] (pattern_design; None: no patterns); lengths W [M, C] (grid.lengths;
    None: no field); the priors pa (dB), px and ps (dB/m, the deviation of a cell and of the difference of two
    adjacent cells), L the active cells' Laplacian. Cells no link crosses are no unknowns and stay 0."""
    from scipy.sparse import block_diag, diags, hstack
    from scipy.sparse.linalg import spsolve

    r = np.asarray(residual_db, np.float64)
    s2 = max(float(np.mean(r ** 2)), 1e-12)
    blocks, reg, active = [], [], None
    if pattern_rows is not None:
        blocks.append(pattern_rows)
        reg.append(diags(np.full(pattern_rows.shape[1], s2 / pattern_prior_db ** 2)))
    if lengths is not None:
        active = np.flatnonzero(np.asarray(lengths.sum(0)).ravel() > 0)
        blocks.append(-lengths[:, active])
        reg.append(diags(np.full(len(active), s2 / field_prior_db_per_m ** 2))
                   + laplacian(grid, active) * (s2 / smooth_prior_db_per_m ** 2))
    if not blocks:
        return None, None
    a = hstack(blocks).tocsr()
    theta = spsolve((a.T @ a + block_diag(reg)).tocsc(), a.T @ r)
    theta = np.atleast_1d(theta)
    pattern = fld = None
    if pattern_rows is not None:
        pattern, theta = theta[:pattern_rows.shape[1]], theta[pattern_rows.shape[1]:]
    if lengths is not None:
        fld = np.zeros(lengths.shape[1])
        fld[active] = theta
    return pattern, fld


def fit_kriging(points_m: np.ndarray, residual_db: np.ndarray, length_m: float, nugget_share: float) -> np.ndarray:
    """Kriging weights w [T] dB (s^2 alpha) of one device's training points points_m [T, 3] m and residuals [T] dB:
    zero-mean prior, exponential kernel of `length_m`, the residuals' mean square split into a signal variance
    s^2 = (1 - nugget_share) ms and a nugget (noise) nugget_share ms; the kriged residual at x is
    exp(-|x - X| / length) @ w."""
    r = np.asarray(residual_db, np.float64)
    ms = max(float(np.mean(r ** 2)), 1e-12)
    signal, noise = (1 - nugget_share) * ms, nugget_share * ms
    k = signal * exponential_kernel(points_m, points_m, length_m) + noise * np.eye(len(r))
    return signal * np.linalg.solve(k, r)
