#!/usr/bin/env python3
"""Convert the Laboratory scenario of the "RTT Indoor localization data set" (Yu et al., MIT licence,
https://github.com/haiyaoyu/RTT-Indoor-localization-data-set) into rfir's inputs.

In the Laboratory scenario six Google Wifi access points (AP1, AP2, AP5..AP8; AP3 and AP4 are listed at
(0, 0), i.e. not deployed) stand around a block of rooms in an open hall, and two people walk with a
phone each along a straight line on either side of the block (user 1 at y = 15.326 m, user 2 at
y = 20.159 m), back and forth over x = 1.25..22.16 m, five times ("circles" 1..5). Every ~0.25 s
the phone logs, per AP, the RSS [dBm] of its Wi-Fi RTT (FTM) exchange and its ground-truth position
(interpolated by the authors along the walked line).

Writes
  links CSV  tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,tx_id,rx_id,split,n_packets,rssi_std_db
             one row per (position cell, AP): the phone's samples binned in --cell-m cells along its
             line; power_db = mean RSS [dBm] over the samples in the cell (an RSS of 0 means "no
             measurement" in the data set and is skipped), n_packets their count, rssi_std_db their
             standard deviation. The phone's position is the transmitter (tx, tx_id = cell index,
             sorted by line then x), the APs the receivers (rx, rx_id = the AP number), as in the
             project's first public survey (anchors on the rx side). split: a random --test-fraction of
             the positions (all their links) is test (1), the rest train (0).
  walls CSV  x0,y0,x1,y1,thickness_m,material: the walls near the walked lines, digitised by hand from
             the data set's "Laboratory floor plan.jpg" (999 x 494 px; no scale bar) and put in metres
             by the affine map that takes the six AP markers drawn on the plan to the APs' coordinates
             (least squares; residuals under 8 cm, printed).

Assumptions (printed and written as comments into the CSV):
  - frequency: the data set does not give the channel; Google Wifi answers Wi-Fi RTT (802.11mc FTM)
    requests on 5 GHz, so every row gets --freq-hz (default 5.2e9).
  - heights: not given; APs at --ap-height-m (1.0), the hand-held phone at --phone-height-m (1.2).
  - transmit power: not given; the header states --tx-power-dbm (default 20 dBm, the usual maximum of
    a 5 GHz access point: with 0 dBm the strongest links would lie 20 dB above free space). The
    imported path gain keeps an unknown constant offset, plus each device's gain (the two users
    carried different phones).
  - walls: thickness and material are not on the plan: the stair core and outer walls drawn thick are
    taken as concrete 0.2 m, the thin room partitions as plasterboard 0.1 m; the hall's south part
    (stairs, a second atrium) and furniture are not modelled.

Usage:
  python scripts/rtt_lab_to_csv.py LAB_DIR --links links.csv --walls walls.csv \
      [--cell-m 0.25] [--min-samples 3] [--test-fraction 0.2] [--seed 0]
LAB_DIR is raw_data/Laboratory of a checkout of the data set (needs AP_idx_Laboratory.csv and the
circle folders 1..5 with their <circle>13.csv and <circle>24.csv).
"""
from __future__ import annotations

import argparse
import csv
import math
import random
import sys
from collections import defaultdict
from pathlib import Path

FREQ_HZ = 5.2e9
SOURCE = "https://github.com/haiyaoyu/RTT-Indoor-localization-data-set"

# Centres of the AP markers (coloured stars) on "Laboratory floor plan.jpg", pixel (column, row), read
# off the image (colour centroids; AP1's olive star by eye). They register the plan to the metric frame.
AP_MARKERS_PX = {1: (395.0, 158.8), 2: (394.5, 102.7), 5: (588.0, 103.1), 6: (578.8, 167.9),
                 7: (640.2, 119.1), 8: (503.4, 90.0)}

# Walls near the walked lines, pixel (column, row) end points of each wall's centre line on the plan,
# found by scanning it for dark pixels; (name, (c0, r0), (c1, r1), thickness_m, material).
CONCRETE, PLASTER = (0.2, "concrete"), (0.1, "plasterboard")
WALLS_PX = [
    # the block the two lines walk around: a stair core (drawn thick) and two rooms (drawn thin)
    ("stair_north", (412, 119), (482, 119), *CONCRETE),
    ("stair_south", (412, 152.5), (482, 152.5), *CONCRETE),
    ("stair_west", (412, 119), (412, 152.5), *CONCRETE),
    ("stair_east", (481.5, 119), (481.5, 152.5), *CONCRETE),
    ("small_room_west", (505, 120), (505, 146), *PLASTER),
    ("small_room_north", (505, 120), (540, 120), *PLASTER),
    ("small_room_south", (505, 146), (540, 146), *PLASTER),
    ("room_north", (540, 120.5), (627, 120.5), *PLASTER),
    ("room_south", (540, 153.5), (627, 153.5), *PLASTER),
    ("room_west", (540, 120.5), (540, 153.5), *PLASTER),
    ("room_east", (627, 120.5), (627, 153.5), *PLASTER),
    # the hall's edges north of the north line
    ("north_west_wall", (400, 99), (455, 99), *CONCRETE),
    ("north_room_wall", (452, 86), (534, 86), *CONCRETE),
    ("north_east_wall", (580, 100.5), (657, 100.5), *CONCRETE),
    # west and east ends, and the room south of AP6
    ("west_wall", (386, 99), (386, 185), *CONCRETE),
    ("east_wall_north", (658, 100.5), (658, 121), *CONCRETE),
    ("east_wall_south", (658, 148), (658, 185), *CONCRETE),
    ("south_room_wall", (552, 173.5), (602, 173.5), *PLASTER),
]


def read_aps(lab: Path) -> dict[int, tuple[float, float]]:
    """AP number -> (x, y) [m] from AP_idx_Laboratory.csv; APs listed at (0, 0) are not deployed."""
    path = lab / "AP_idx_Laboratory.csv"
    aps = {}
    with path.open(encoding="utf-8-sig") as f:
        for row in csv.DictReader(f):
            name = (row.get("") or next(iter(row.values()))).strip()
            x, y = float(row["x"]), float(row["y"])
            if name.startswith("AP") and (x, y) != (0.0, 0.0):
                aps[int(name[2:])] = (x, y)
    if not aps:
        sys.exit(f"{path}: no AP coordinates found")
    return aps


def fit_axis_map(aps: dict[int, tuple[float, float]]) -> tuple[tuple[float, float], tuple[float, float], float]:
    """Least-squares x = ax*col + bx, y = ay*row + by from the AP markers; returns the two (scale,
    offset) pairs and the largest marker residual [m]."""
    ids = [k for k in AP_MARKERS_PX if k in aps]
    if len(ids) < 2:
        sys.exit(f"AP_idx_Laboratory.csv: {len(ids)} of the APs drawn on the plan ({sorted(AP_MARKERS_PX)}) "
                 "listed, at least 2 needed to register the plan")
    out = []
    for axis in (0, 1):
        p = [AP_MARKERS_PX[k][axis] for k in ids]
        m = [aps[k][axis] for k in ids]
        n, sp, sm = len(p), sum(p), sum(m)
        spp = sum(v * v for v in p)
        spm = sum(a * b for a, b in zip(p, m))
        scale = (n * spm - sp * sm) / (n * spp - sp * sp)
        out.append((scale, (sm - scale * sp) / n))
    worst = max(math.hypot(out[0][0] * AP_MARKERS_PX[k][0] + out[0][1] - aps[k][0],
                           out[1][0] * AP_MARKERS_PX[k][1] + out[1][1] - aps[k][1]) for k in ids)
    return out[0], out[1], worst


def read_samples(lab: Path) -> list[tuple[int, float, float, dict[int, float]]]:
    """(user, x, y, {ap: rss_dbm}) for every logged sample; an RSS of 0 in the file (none) is left out."""
    samples = []
    for circle in range(1, 6):
        for pair in ("13", "24"):
            path = lab / str(circle) / f"{circle}{pair}.csv"
            if not path.exists():
                sys.exit(f"{path}: missing (LAB_DIR must be raw_data/Laboratory of the data set)")
            with path.open(encoding="utf-8-sig") as f:
                reader = csv.DictReader(f)
                gx = next((c for c in reader.fieldnames or [] if c.endswith("Ground Truth_x")), None)
                if gx is None:
                    sys.exit(f"{path}: no 'Ground Truth_x' column")
                gy = gx[:-1] + "y"
                aps = [(int(c.split()[0][2:]), c) for c in reader.fieldnames if c.endswith("RSS (dBm)")]
                for row in reader:
                    rss = {ap: float(row[col]) for ap, col in aps}
                    samples.append((int(float(row["user"])), float(row[gx]), float(row[gy]),
                                    {ap: v for ap, v in rss.items() if v != 0.0}))
    return samples


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("lab", type=Path, help="raw_data/Laboratory of a checkout of the data set")
    ap.add_argument("--links", type=Path, required=True)
    ap.add_argument("--walls", type=Path, required=True)
    ap.add_argument("--cell-m", type=float, default=0.25, help="cell length along a walked line [m]")
    ap.add_argument("--min-samples", type=int, default=3, help="drop a (cell, AP) with fewer samples")
    ap.add_argument("--test-fraction", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--freq-hz", type=float, default=FREQ_HZ)
    ap.add_argument("--ap-height-m", type=float, default=1.0)
    ap.add_argument("--phone-height-m", type=float, default=1.2)
    ap.add_argument("--tx-power-dbm", type=float, default=20.0,
                    help="nominal transmit power written to the header (not in the data set)")
    a = ap.parse_args(argv)

    aps = read_aps(a.lab)
    (sx, ox), (sy, oy), worst = fit_axis_map(aps)
    print(f"plan registration: x = {sx:.5f} col + {ox:.3f}, y = {sy:.5f} row + {oy:.3f} m; "
          f"largest AP-marker residual {worst:.3f} m")

    # cell key: (user, round(y, 3), cell index along x)
    cells: dict[tuple, dict] = defaultdict(lambda: {"xs": [], "rss": defaultdict(list)})
    for user, x, y, rss in read_samples(a.lab):
        c = cells[(user, round(y, 3), math.floor(x / a.cell_m))]
        c["xs"].append(x)  # the cell's position: the mean over all its samples
        for ap_id, v in rss.items():
            if ap_id in aps:
                c["rss"][ap_id].append(v)
    # links per cell: (ap, mean, std, count) of the APs with at least --min-samples samples there
    per_cell = {}
    for key, c in cells.items():
        links = []
        for ap_id in sorted(c["rss"]):
            v = c["rss"][ap_id]
            if len(v) >= a.min_samples:
                mean = sum(v) / len(v)
                links.append((ap_id, mean, math.sqrt(sum((s - mean) ** 2 for s in v) / len(v)), len(v)))
        if links:
            per_cell[key] = links
    keys = sorted(per_cell, key=lambda k: (k[1], k[2]))
    rng = random.Random(a.seed)
    n_test = round(a.test_fraction * len(keys))
    test = set(rng.sample(range(len(keys)), n_test))

    a.links.parent.mkdir(parents=True, exist_ok=True)
    n_links = 0
    with a.links.open("w", newline="") as f:
        f.write(f"# RTT Indoor localization data set (Yu et al.), Laboratory scenario, MIT licence\n"
                f"# {SOURCE}\n"
                f"# power_db: mean Wi-Fi RTT RSS in dBm over the phone's samples in a {a.cell_m} m cell\n"
                f"# transmit power not given: nominal {a.tx_power_dbm:g} dBm (a 5 GHz access point's usual "
                f"maximum), an unknown constant offset remains\n"
                f"# channel not given: nominal {a.freq_hz:.4g} Hz (Google Wifi answers RTT on 5 GHz)\n"
                f"# heights not given: APs {a.ap_height_m} m, phone {a.phone_height_m} m\n"
                f"# power = rssi\n# tx_power_dbm = {a.tx_power_dbm:g}\n")
        w = csv.writer(f)
        w.writerow(["tx_x", "tx_y", "tx_z", "rx_x", "rx_y", "rx_z", "freq_hz", "power_db", "tx_id", "rx_id",
                    "split", "n_packets", "rssi_std_db"])
        for idx, key in enumerate(keys):
            xs = cells[key]["xs"]
            x = sum(xs) / len(xs)
            for ap_id, mean, std, count in per_cell[key]:
                rx, ry = aps[ap_id]
                w.writerow([round(x, 3), key[1], a.phone_height_m, rx, ry, a.ap_height_m, a.freq_hz,
                            round(mean, 2), idx, ap_id, int(idx in test), count, round(std, 2)])
                n_links += 1
    print(f"{a.links}: {n_links} links, {len(keys)} positions ({n_test} test), {len(aps)} APs")

    with a.walls.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x0", "y0", "x1", "y1", "thickness_m", "material"])
        for _, (c0, r0), (c1, r1), t, mat in WALLS_PX:
            w.writerow([round(sx * c0 + ox, 3), round(sy * r0 + oy, 3), round(sx * c1 + ox, 3),
                        round(sy * r1 + oy, 3), t, mat])
    print(f"{a.walls}: {len(WALLS_PX)} walls")
    return 0


if __name__ == "__main__":
    sys.exit(main())
