#!/usr/bin/env python3
"""Convert the "Position Annotated BLE RSSI Dataset for Indoor Localization" (Danis et al., CC0 1.0,
https://github.com/philotuxo/Position-Annotated-BLE-RSSI-Dataset) into rfir's inputs.

Writes
  links CSV  tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,tx_id,rx_id,split,n_packets,rssi_std_db
             one row per (beacon position, sensor): the mean RSSI [dBm] of the packets that sensor
             logged while the beacon stood at that reference point (hst/set_*/<sensor>_<x>_<y>_<z>.mbd).
             The beacon transmits (tx = reference point), the 12 fixed sensors receive (rx).
             tx_id: index of the reference point (sorted by x, y, z); rx_id: the sensor's number
             (sensorNN -> NN; rfir wants integer ids).
  walls CSV  x0,y0,x1,y1,thickness_m,material: the walls and pillars of the area map (map/tetam.png),
             digitised by hand from the pixel outlines; pixel -> metres by cnf/tetam.par.

Frame: the data set's own (x down the map image, y to the right, z up; origin at the map's top-left
corner). It is left-handed when drawn as the image is shown, but it is a plain right-handed metric
frame in itself (x, y, z = up) - only the picture is mirrored.

Assumptions (printed and written as comments into the CSV):
  - frequency: BLE advertising hops over channels 37/38/39 (2402, 2426, 2480 MHz) and the logs do not
    say which; every row gets --freq-hz (default 2.44e9, the middle).
  - transmit power: not stated in the data set; power_db is RSSI [dBm] with tx_power_dbm = 0, so the
    imported "path gain" carries an unknown constant offset (plus each sensor's own gain).
  - antennas at points closer than --clearance-m to a digitised wall or pillar (several sensors hang
    on walls/pillars) are pushed out to that clearance; every push is printed and noted in the CSV.

Usage:
  python scripts/public_survey_to_csv.py RAW_DIR --links links.csv --walls walls.csv \
      [--sets set_1 set_2] [--min-packets 20] [--test-fraction 0.2] [--seed 0] [--max-links 1500]
RAW_DIR is a checkout of the data set's repository (needs cnf/ and hst/).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import random
import re
import sys
from collections import defaultdict
from pathlib import Path

FREQ_HZ = 2.44e9

# ---------------------------------------------------------------------------------------------
# Floor plan, digitised from map/tetam.png (640 x 718 px). Each entry is the line a wall's ROOM-SIDE
# face makes in the image, in pixel (column, row), and the pixel direction of the wall mass behind
# it (outward); pillars are given as pixel rectangles. Wall thickness is not drawn (the map shows
# thin outlines): ASSUMED 0.25 m for the outer walls, pillars as drawn. Material is not stated in the
# data set: ASSUMED concrete throughout (a university lab; walls and columns).
# Lines found by scanning the image for runs of dark pixels (R+G+B < 200) of >= 10 px.
# ---------------------------------------------------------------------------------------------
OUTER_T = 0.25
STUB_T = 0.12
# (name, (c0, r0), (c1, r1), outward (dc, dr), thickness_m or None for OUTER_T)
FACES = [
    ("north_wall", (22, 8.5), (617.5, 8.5), (0, -1), None),          # map top edge: x = 0
    ("west_wall_a", (22, 8.5), (22, 361), (-1, 0), None),            # map left edge, upper room
    ("west_corridor_n", (8, 361), (22, 361), (0, -1), STUB_T),       # corridor opening x 10.4..12.3
    ("west_corridor_s", (8, 424), (31, 424), (0, 1), STUB_T),
    ("west_wall_b", (31, 424), (31, 644), (-1, 0), None),            # map left edge, lower room
    ("west_stub_c", (8, 644), (31, 644), (0, 1), STUB_T),
    ("south_wall", (8, 707.5), (630, 707.5), (0, 1), None),          # map bottom edge: x = 20.66
    ("east_wall_a", (617.5, 8.5), (617.5, 300), (1, 0), None),       # map right edge, upper room
    ("east_box_n", (592.5, 300), (617.5, 300), (0, 1), STUB_T),
    ("east_box_w1", (592.5, 300), (592.5, 337), (1, 0), STUB_T),
    ("east_box_w2", (589, 337), (589, 361), (1, 0), STUB_T),
    ("east_corridor_n", (589, 361), (630, 361), (0, -1), STUB_T),
    ("east_corridor_s", (589, 424), (630, 424), (0, 1), STUB_T),
    ("east_wall_b", (589, 424), (589, 456), (1, 0), None),
    ("east_niche_n", (589, 456), (617, 456), (0, -1), STUB_T),
    ("east_niche_e", (617, 456), (617, 541), (1, 0), None),          # behind the cabinet (inferred)
    ("east_niche_s", (586, 541), (617, 541), (0, 1), STUB_T),
    ("east_wall_c", (586, 541), (586, 644), (1, 0), None),
    ("east_stub_d", (586, 644), (630, 644), (0, 1), STUB_T),
]
# (name, c0, r0, c1, r1): pillars / columns and wall-embedded column casings
PILLARS = [
    ("pillar_n1", 216, 8.5, 231, 33), ("pillar_n2", 418, 8.5, 433, 34), ("pillar_w", 22, 209, 44.5, 252),
    ("pillar_a", 210, 224, 234.5, 247), ("pillar_b", 414, 224, 437, 247),
    ("pillar_c", 211, 426, 235, 449), ("pillar_d", 414, 426, 437, 449),
    ("pillar_e", 210, 609, 250, 644), ("pillar_f", 414, 620, 437, 644),
]


def pixel_frame(par_path: Path):
    """(col, row) -> (x, y) metres, from cnf/tetam.par (lib/btImageScene.py's convention)."""
    par = json.loads(par_path.read_text())   # the data set writes it as JSON
    (oc, orow), (d0, d1, s0, s1), p = par["origin"], par["direction"], par["parity"]
    # pixel x (column) = origin.x + coord[d0] / p * s0; pixel y (row) = origin.y + coord[d1] / p * s1
    def to_m(c, r):
        out = [0.0, 0.0]
        out[d0] = (c - oc) * p / s0
        out[d1] = (r - orow) * p / s1
        return out[0], out[1]
    return to_m, p


def walls_m(to_m) -> list[dict]:
    """Wall rows: centre line (face moved outward by half the thickness), thickness, material, name."""
    rows = []
    for name, a, b, (dc, dr), t in FACES:
        t = OUTER_T if t is None else t
        (x0, y0), (x1, y1) = to_m(*a), to_m(*b)
        ox, oy = to_m(a[0] + dc, a[1] + dr)
        nx, ny = ox - x0, oy - y0
        n = math.hypot(nx, ny)
        nx, ny = nx / n * t / 2, ny / n * t / 2
        rows.append(dict(name=name, x0=x0 + nx, y0=y0 + ny, x1=x1 + nx, y1=y1 + ny, thickness_m=t,
                         material="concrete"))
    for name, c0, r0, c1, r1 in PILLARS:
        (xa, ya), (xb, yb) = to_m(c0, r0), to_m(c1, r1)
        xa, xb = sorted((xa, xb))
        ya, yb = sorted((ya, yb))
        if xb - xa >= yb - ya:      # centre line along the longer side
            ym = (ya + yb) / 2
            rows.append(dict(name=name, x0=xa, y0=ym, x1=xb, y1=ym, thickness_m=yb - ya, material="concrete"))
        else:
            xm = (xa + xb) / 2
            rows.append(dict(name=name, x0=xm, y0=ya, x1=xm, y1=yb, thickness_m=xb - xa, material="concrete"))
    return rows


def push_clear(p, walls, clearance):
    """Move 2-D point p out of every wall box grown by `clearance`; returns the new point."""
    x, y = p
    for _ in range(10):
        moved = False
        for w in walls:
            ux, uy = w["x1"] - w["x0"], w["y1"] - w["y0"]
            L = math.hypot(ux, uy)
            ux, uy = ux / L, uy / L
            vx, vy = -uy, ux
            s = (x - w["x0"]) * ux + (y - w["y0"]) * uy          # along the wall
            d = (x - w["x0"]) * vx + (y - w["y0"]) * vy          # across
            h = w["thickness_m"] / 2 + clearance
            if -clearance < s < L + clearance and abs(d) < h:
                # least move out of the grown box
                cand = [(h - d, (vx, vy)), (h + d, (-vx, -vy)), (s + clearance, (-ux, -uy)),
                        (L + clearance - s, (ux, uy))]
                amt, (ex, ey) = min(cand, key=lambda c: c[0])
                x, y = x + (amt + 1e-3) * ex, y + (amt + 1e-3) * ey
                moved = True
        if not moved:
            break
    return x, y


MBD = re.compile(r"^(sensor\d+)_(-?\d+\.\d+)_(-?\d+\.\d+)_(-?\d+\.\d+)\.mbd$")


def read_sensors(dev_path: Path) -> dict:
    """alias -> (mac, (x, y, z)) from cnf/tetam.dev."""
    for line in dev_path.read_text().splitlines():
        if line.startswith("Dongles:"):
            d = json.loads(line[len("Dongles:"):])
            return {v[2]: (mac, tuple(float(c) for c in v[0])) for mac, v in d.items()}
    raise SystemExit(f"{dev_path}: no 'Dongles:' line")


def read_links(raw: Path, sets: list[str], sensors: dict) -> dict:
    """(position, sensor alias) -> list of RSSI [dBm] over the chosen sets."""
    mac_alias = {mac: a for a, (mac, _) in sensors.items()}
    out = defaultdict(list)
    for s in sets:
        folder = raw / "hst" / s
        files = sorted(folder.glob("*.mbd"))
        if not files:
            raise SystemExit(f"{folder}: no .mbd files")
        for f in files:
            m = MBD.match(f.name)
            if not m:
                continue
            alias, pos = m.group(1), tuple(float(m.group(i)) for i in (2, 3, 4))
            for line in f.read_text().splitlines():
                parts = line.split(",")
                if len(parts) < 4:
                    continue
                if mac_alias.get(parts[1]) != alias:       # every line of a file is its own sensor
                    continue
                out[(pos, alias)].append(float(parts[3]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", type=Path, help="checkout of philotuxo/Position-Annotated-BLE-RSSI-Dataset")
    ap.add_argument("--links", type=Path, required=True, help="links CSV to write")
    ap.add_argument("--walls", type=Path, required=True, help="walls CSV to write (x0,y0,x1,y1,thickness_m,material)")
    ap.add_argument("--sets", nargs="+", default=["set_1", "set_2"], help="hst/ sub-folders to read")
    ap.add_argument("--freq-hz", type=float, default=FREQ_HZ)
    ap.add_argument("--min-packets", type=int, default=20, help="drop links with fewer packets")
    ap.add_argument("--test-fraction", type=float, default=0.2, help="random share of beacon POSITIONS in test")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-links", type=int, default=0, help="keep at most this many links (whole positions; 0: all)")
    ap.add_argument("--clearance-m", type=float, default=0.10,
                    help="push antennas this far off walls (rf-fit needs >= 2 cm from any surfel disc, whose reach passes box edges)")
    ap.add_argument("--decimals", type=int, default=2)
    a = ap.parse_args(argv)

    to_m, parity = pixel_frame(a.raw / "cnf" / "tetam.par")
    walls = walls_m(to_m)
    sensors = read_sensors(a.raw / "cnf" / "tetam.dev")
    notes = []

    def place(label, p):
        q = push_clear(p[:2], walls, a.clearance_m)
        if math.hypot(q[0] - p[0], q[1] - p[1]) > 1e-9:
            q = (round(q[0], 3), round(q[1], 3))
            notes.append(f"{label} moved ({p[0]:.2f} {p[1]:.2f}) -> ({q[0]:.3f} {q[1]:.3f}) to clear a wall")
        return (q[0], q[1], p[2])

    rx_pos = {alias: place(alias, xyz) for alias, (_, xyz) in sorted(sensors.items())}
    samples = read_links(a.raw, a.sets, sensors)
    positions = sorted({pos for pos, _ in samples})
    pos_id = {p: i for i, p in enumerate(positions)}   # rfir ids are integers
    tx_pos = {p: place(f"position {pos_id[p]}", p) for p in positions}

    rng = random.Random(a.seed)
    order = positions[:]
    rng.shuffle(order)
    if a.max_links:
        kept, count = [], 0
        for p in order:
            n = sum(1 for s in sensors if len(samples.get((p, s), [])) >= a.min_packets)
            if count + n > a.max_links:
                continue
            kept.append(p)
            count += n
        order = kept
    n_test = round(a.test_fraction * len(order))
    test = set(order[:n_test])

    rows = []
    for p in sorted(order):
        for s in sorted(sensors):
            v = samples.get((p, s), [])
            if len(v) < a.min_packets:
                continue
            mean = sum(v) / len(v)
            std = math.sqrt(sum((x - mean) ** 2 for x in v) / len(v))
            rows.append([*tx_pos[p], *rx_pos[s], a.freq_hz, round(mean, a.decimals), pos_id[p], int(s[len("sensor"):]),
                         1 if p in test else 0, len(v), round(std, 2)])

    a.links.parent.mkdir(parents=True, exist_ok=True)
    with open(a.links, "w", newline="") as fh:
        fh.write("# Position Annotated BLE RSSI Dataset (Danis et al.), CC0 1.0\n")
        fh.write("# https://github.com/philotuxo/Position-Annotated-BLE-RSSI-Dataset hst sets: "
                 + " ".join(a.sets) + "\n")
        fh.write("# power_db: mean RSSI in dBm over the packets one sensor logged at one beacon position\n")
        fh.write("# transmit power unknown: RSSI with tx power 0 dBm, an unknown constant offset remains\n")
        fh.write("# BLE advertising channels 37 38 39 mixed; one nominal frequency\n")
        for n in notes:
            fh.write(f"# {n}\n")
        fh.write("# power = rssi\n# tx_power_dbm = 0\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["tx_x", "tx_y", "tx_z", "rx_x", "rx_y", "rx_z", "freq_hz", "power_db", "tx_id", "rx_id",
                    "split", "n_packets", "rssi_std_db"])
        w.writerows(rows)
    a.walls.parent.mkdir(parents=True, exist_ok=True)
    with open(a.walls, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["x0", "y0", "x1", "y1", "thickness_m", "material"])
        for r in walls:
            w.writerow([f"{r['x0']:.3f}", f"{r['y0']:.3f}", f"{r['x1']:.3f}", f"{r['y1']:.3f}",
                        f"{r['thickness_m']:.3f}", r["material"]])
    n_test_links = sum(r[10] for r in rows)
    print(f"{len(order)} beacon positions ({len(test)} test), {len(sensors)} sensors, {len(rows)} links "
          f"({n_test_links} test), {len(walls)} wall rows; m/px {parity:.5f}", file=sys.stderr)
    for n in notes:
        print("  " + n, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
