"""`rfir import csv` options (--average, --split, unit flags, --column) and the unit checks, property
based: every option does what it says on any survey, and every bad input is one line on stderr
naming the flag that fixes it, with its exit code and nothing written (the -o path is absent or
byte-identical to what was there)."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, validate_artifact, write_artifact
from rfir_cli.main import app

PROPS = settings(max_examples=15, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
HEADER = ["tx_x", "tx_y", "tx_z", "rx_x", "rx_y", "rx_z", "freq_hz", "power_db"]
C = 299_792_458.0


def free_space_db(d_m, f_hz):
    """Friis path gain [dB] of isotropic antennas d_m metres apart at f_hz."""
    return 20 * math.log10(C / f_hz / (4 * math.pi * d_m))


@st.composite
def surveys(draw, min_links=2, max_links=8, max_repeats=1, n_tx=None):
    """Links in a 6 x 5 x 3 m room, 1..3 frequencies, path gains 0..15 dB below free space: a list of
    (tx, rx, freq_hz, [path gain dB per sample]) per link and frequency."""
    n_tx = n_tx or draw(st.integers(1, 3))
    txs = [(draw(st.floats(0.2, 5.8)), draw(st.floats(0.2, 4.8)), 2.0 + t * 0.1) for t in range(n_tx)]
    freqs = draw(st.lists(st.sampled_from([900e6, 2.4e9, 5.8e9]), min_size=1, max_size=3, unique=True))
    links = []
    for i in range(draw(st.integers(min_links, max_links))):
        tx = txs[i % n_tx]
        rx = (draw(st.floats(0.0, 6.0)), draw(st.floats(0.0, 5.0)), 0.5 + i * 0.01)  # distinct receivers
        d = math.dist(tx, rx)
        for f in freqs:
            n = draw(st.integers(1, max_repeats))
            links.append((tx, rx, f, [free_space_db(d, f) - draw(st.floats(0.0, 15.0)) for _ in range(n)]))
    return links


def rows_of(links, fmt=lambda v: f"{v:.6f}"):
    """CSV rows (one per sample) of a survey; fmt writes power_db."""
    out = []
    for tx, rx, f, samples in links:
        out += [",".join(f"{c:.6f}" for c in (*tx, *rx)) + f",{f:g}," + fmt(v) for v in samples]
    return out


def write_csv(tmp_path, rows, header=HEADER, name="links.csv"):
    path = tmp_path / name
    path.write_text("\n".join([",".join(header)] + list(rows)) + "\n")
    return path


def run(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def existing_artifact(path):
    """A valid artifact already at -o, to check that a refused import leaves it byte-identical."""
    write_artifact(path, "measurements", {"tx_pos": np.zeros((1, 3)), "rx_pos": np.ones((1, 3)),
                                          "freq_hz": np.array([2.4e9]), "path_gain_db": np.array([[-50.0]])},
                   attrs={"task": "rssi", "scene": "before"})
    return path.read_bytes()


def assert_refused(result, code, *fragments, out=None, before=None):
    """Exit code, one line on stderr naming the fragments, no traceback, nothing written."""
    assert result.exit_code == code, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    if out is not None:
        assert (out.read_bytes() == before) if before is not None else not out.exists()
        assert not list(out.parent.glob(f".{out.name}.partial-*"))


# ---- --average ----------------------------------------------------------------------------------

@PROPS
@given(links=surveys(max_repeats=4), how=st.sampled_from(["mean-db", "mean-power"]))
def test_average_stores_mean_count_and_spread(tmp_path, links, how):
    path = write_csv(tmp_path, rows_of(links))
    out = tmp_path / "m.h5"
    result = run("import", "csv", path, "-o", out, "--average", how)
    assert result.exit_code == 0, result.stderr
    art = read_artifact(out, "measurements")
    freqs = list(art["freq_hz"])
    n_links = len(art["tx_pos"])
    n_rows = sum(len(s) for *_, s in links)
    assert f"averaged from {n_rows} rows" in result.stdout and f"{n_links} links" in result.stdout
    for tx, rx, f, samples in links:
        v = np.round(samples, 6)
        link = int(np.flatnonzero(np.all(np.abs(art["rx_pos"] - np.round(rx, 6)) < 1e-9, axis=1))[0])
        k = freqs.index(f)
        want = v.mean() if how == "mean-db" else 10 * np.log10(np.mean(10 ** (v / 10)))
        assert art["path_gain_db"][link, k] == pytest.approx(want, abs=1e-9)
        assert art["sample_std_db"][link, k] == pytest.approx(np.std(v, ddof=1) if len(v) > 1 else 0.0, abs=1e-9)
    counts = {}
    for tx, rx, f, samples in links:
        key = tuple(np.round(rx, 6))
        counts[key] = min(counts.get(key, 99), len(samples))
    for key, n in counts.items():
        link = int(np.flatnonzero(np.all(np.abs(art["rx_pos"] - np.array(key)) < 1e-9, axis=1))[0])
        assert art["sample_count"][link] == n
    assert validate_artifact(out) == []


@PROPS
@given(links=surveys(max_repeats=1), spread=st.floats(0.5, 6.0), pre=st.booleans())
def test_repeated_rows_without_average_are_refused_naming_the_flag(tmp_path, links, spread, pre):
    tx, rx, f, samples = links[0]
    links = [(tx, rx, f, samples + [samples[0] - spread])] + links[1:]
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", out)
    assert_refused(result, 2, "the same link and frequency with different values", "--average mean-db",
                   out=out, before=before)


def test_average_refuses_an_unknown_mode(tmp_path):
    links = [((0, 0, 1), (3, 0, 1), 2.4e9, [-55.0])]
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", tmp_path / "m.h5", "--average", "median")
    assert_refused(result, 4, "--average 'median'", out=tmp_path / "m.h5")


# ---- --split ------------------------------------------------------------------------------------

@PROPS
@given(links=surveys(min_links=4, max_links=12), share=st.floats(0.05, 0.95), seed=st.integers(0, 2**31))
def test_split_random_share_is_deterministic_for_the_seed(tmp_path, links, share, seed):
    path = write_csv(tmp_path, rows_of(links))
    splits = []
    for name in ("a.h5", "b.h5"):
        result = run("--seed", seed, "import", "csv", path, "-o", tmp_path / name, "--split", f"random:{share}")
        assert result.exit_code == 0, result.stderr
        splits.append(read_artifact(tmp_path / name)["split"])
    n = len(splits[0])
    np.testing.assert_array_equal(splits[0], splits[1])
    assert splits[0].sum() == min(max(1, round(share * n)), n - 1)
    assert set(np.unique(splits[0])) == {0, 1}
    assert f"seed {seed}" in result.stdout


@PROPS
@given(links=surveys(min_links=6, max_links=12, n_tx=3), held=st.integers(1, 2), seed=st.integers(0, 1000))
def test_split_holdout_tx_holds_out_whole_transmitters(tmp_path, links, held, seed):
    out = tmp_path / "m.h5"
    result = run("--seed", seed, "import", "csv", write_csv(tmp_path, rows_of(links)), "-o", out,
                 "--split", f"holdout-tx:{held}")
    assert result.exit_code == 0, result.stderr
    art = read_artifact(out)
    tx = [tuple(t) for t in np.round(art["tx_pos"], 6)]
    test_tx = {t for t, s in zip(tx, art["split"]) if s == 1}
    train_tx = {t for t, s in zip(tx, art["split"]) if s == 0}
    assert len(test_tx) == held and not test_tx & train_tx and train_tx


@PROPS
@given(links=surveys(min_links=6, max_links=12), size=st.floats(0.5, 3.0), seed=st.integers(0, 1000))
def test_split_block_holds_out_whole_receiver_squares(tmp_path, links, size, seed):
    out = tmp_path / "m.h5"
    if out.exists():
        out.unlink()                                     # left by an earlier example
    result = run("--seed", seed, "import", "csv", write_csv(tmp_path, rows_of(links)), "-o", out,
                 "--split", f"block:{size}")
    squares = {tuple(np.floor(np.round(rx[:2], 6) / size)) for _, rx, _, _ in links}
    if len(squares) < 2:
        assert_refused(result, 4, "pick a smaller SIZE", out=out)
        return
    assert result.exit_code == 0, result.stderr
    art = read_artifact(out)
    cell = [tuple(np.floor(p[:2] / size)) for p in art["rx_pos"]]
    for c in set(cell):
        assert len({s for s, k in zip(art["split"], cell) if k == c}) == 1     # a square is wholly train or test
    assert 0 < art["split"].sum() < len(art["split"])


@PROPS
@given(links=surveys(), protocol=st.sampled_from(["random:0.2", "holdout-tx:1", "block:1"]), pre=st.booleans())
def test_split_refused_when_the_file_has_a_split_column(tmp_path, links, protocol, pre):
    rows = [r + ",train" for r in rows_of(links)]
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    result = run("import", "csv", write_csv(tmp_path, rows, HEADER + ["split"]), "-o", out, "--split", protocol)
    assert_refused(result, 4, "already has a split column", out=out, before=before)


@pytest.mark.parametrize("protocol, message", [
    ("random:1.5", "expected random:SHARE"), ("holdout-tx:0", "expected random:SHARE"), ("blocks:2", "expected"),
    ("holdout-tx:5", "holding out 5 leaves none"), ("block:100", "pick a smaller SIZE"),
])
def test_split_bad_protocols_are_one_line(tmp_path, protocol, message):
    links = [((1, 1, 2), (x, 2, 1), 2.4e9, [free_space_db(math.dist((1, 1, 2), (x, 2, 1)), 2.4e9) - 3]) for x in (3, 4, 5)]
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", tmp_path / "m.h5", "--split", protocol)
    assert_refused(result, 4, f"--split {protocol!r}", message, out=tmp_path / "m.h5")


def test_split_by_transmitter_or_block_is_for_the_rssi_task(tmp_path):
    rows = ["3,0,0,3,0,0.002,2.4e9,-50,0,3", "0,-3,0,0,-3,0.002,2.4e9,-50,90,3"]
    path = write_csv(tmp_path, rows, HEADER + ["aspect_deg", "range_m"])
    result = run("import", "csv", path, "-o", tmp_path / "m.h5", "--split", "block:1")
    assert_refused(result, 4, "block is for the rssi task", "use random:SHARE", out=tmp_path / "m.h5")
    assert run("import", "csv", path, "-o", tmp_path / "m.h5", "--split", "random:0.5").exit_code == 0
    assert sorted(read_artifact(tmp_path / "m.h5")["split"]) == [0, 1]


def test_no_split_column_is_a_note_not_an_error(tmp_path):
    links = [((0, 0, 1), (3, 0, 1), 2.4e9, [-55.0]), ((0, 0, 1), (0, 4, 1), 2.4e9, [-58.0])]
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", tmp_path / "m.h5")
    assert result.exit_code == 0
    assert "no split column: every link is training; pass --split random:SHARE" in result.stdout
    assert "holdout-tx:N (rssi task" in result.stdout and "block:SIZE" in result.stdout
    assert "assumed (no flag given): power_db is path gain in dB" in result.stdout


# ---- units and column names ---------------------------------------------------------------------

@PROPS
@given(links=surveys(), unit=st.sampled_from(["mW", "W", "dBm"]), tx_dbm=st.floats(-10.0, 30.0))
def test_power_units_are_converted_to_path_gain(tmp_path, links, unit, tx_dbm):
    to_file = {"mW": lambda dbm: 10 ** (dbm / 10), "W": lambda dbm: 10 ** (dbm / 10 - 3), "dBm": lambda dbm: dbm}[unit]
    rows = rows_of(links, fmt=lambda pg: repr(to_file(pg + tx_dbm)))
    out = tmp_path / "m.h5"
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, "--power-unit", unit, "--tx-power-dbm", tx_dbm)
    assert result.exit_code == 0, result.stderr
    art = read_artifact(out)
    assert art.attrs["power"] == "rssi" and art.attrs["tx_power_dbm"] == tx_dbm
    want = sorted(s[0] for *_, s in links)
    np.testing.assert_allclose(sorted(art["path_gain_db"].ravel()), want, atol=1e-6)


@PROPS
@given(links=surveys(), unit=st.sampled_from(["mW", "W", "dBm"]), pre=st.booleans())
def test_received_power_units_need_the_tx_power(tmp_path, links, unit, pre):
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    rows = rows_of(links, fmt=lambda pg: repr(10 ** (pg / 10)) if unit != "dBm" else f"{pg:.3f}")
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, "--power-unit", unit)
    assert_refused(result, 2, "power = rssi needs tx_power_dbm", "--tx-power-dbm", out=out, before=before)


def test_linear_power_cells_must_be_positive(tmp_path):
    rows = ["0,0,1,3,0,1,2.4e9,1e-6", "0,0,1,0,4,1,2.4e9,-2e-6"]
    out = tmp_path / "m.h5"
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, "--power-unit", "mW", "--tx-power-dbm", "10")
    assert_refused(result, 2, "line 3, column power_db: '-2e-6' is not a positive power in mW", out=out)
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, "--power-unit", "mW", "--power", "path_gain")
    assert_refused(result, 4, "--power-unit mW is received power", out=out)


@PROPS
@given(links=surveys(), unit=st.sampled_from(["Hz", "kHz", "MHz", "GHz"]), pos=st.sampled_from(["m", "cm", "mm"]),
       via_scale=st.booleans())
def test_frequency_and_position_units(tmp_path, links, unit, pos, via_scale):
    f_div = {"Hz": 1, "kHz": 1e3, "MHz": 1e6, "GHz": 1e9}[unit]
    p_mul = {"m": 1, "cm": 100, "mm": 1000}[pos]
    rows = []
    for tx, rx, f, samples in links:
        rows += [",".join(f"{c * p_mul:.6f}" for c in (*tx, *rx)) + f",{f / f_div!r},{v:.6f}" for v in samples]
    flags = ["--position-scale", 1 / p_mul] if via_scale else ["--position-unit", pos]
    out = tmp_path / "m.h5"
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, "--freq-unit", unit, *flags)
    assert result.exit_code == 0, result.stderr
    art = read_artifact(out)
    np.testing.assert_allclose(sorted(art["freq_hz"]), sorted({f for *_, f, _ in links}), rtol=1e-12)
    receivers = {tuple(round(c, 6) for c in rx) for _, rx, _, _ in links}
    np.testing.assert_allclose(np.sort(art["rx_pos"][:, 0]), np.sort([rx[0] for rx in receivers]), atol=1e-6)
    assert art.provenance.extra["position_scale"] == pytest.approx(1 / p_mul)


@PROPS
@given(scale=st.sampled_from(["0", "-1", "-0.01", "nan", "inf"]), pre=st.booleans())
def test_non_positive_position_scale_is_refused(tmp_path, scale, pre):
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    path = write_csv(tmp_path, rows_of([((0, 0, 1), (3, 0, 1), 2.4e9, [-55.0])]))
    result = run("import", "csv", path, "-o", out, "--position-scale", scale)
    assert_refused(result, 4, "--position-scale", "must be a positive number", out=out, before=before)


@pytest.mark.parametrize("flags, code, message", [
    (["--power-unit", "dBW"], 4, "--power-unit 'dBW': expected dB, dBm, mW, W"),
    (["--freq-unit", "THz"], 4, "--freq-unit 'THz': expected Hz, kHz, MHz, GHz"),
    (["--position-unit", "inch"], 4, "--position-unit 'inch': expected m, cm, mm"),
    (["--position-unit", "cm", "--position-scale", "0.001"], 4, "disagree"),
    (["--column", "power_db"], 4, "expected NAME=CSVNAME"),
    (["--column", "power=rssi"], 4, "'power' is not an rfir column"),
    (["--column", "power_db=rssi", "--column", "power_db=x"], 4, "given twice"),
    (["--column", "power_db=nope"], 2, "--column power_db=nope: no such column in the file"),
])
def test_bad_unit_and_column_flags_are_one_line(tmp_path, flags, code, message):
    path = write_csv(tmp_path, rows_of([((0, 0, 1), (3, 0, 1), 2.4e9, [-55.0])]))
    result = run("import", "csv", path, "-o", tmp_path / "m.h5", *flags)
    assert_refused(result, code, message, out=tmp_path / "m.h5")


@PROPS
@given(links=surveys(), names=st.permutations(["x", "y", "z", "rssi", "f"]), extra=st.booleans())
def test_column_mapping_reads_renamed_columns(tmp_path, links, names, extra):
    """A file with its own names (columns in any order) imports like the canonical file."""
    canonical = write_csv(tmp_path, rows_of(links), name="canonical.csv")
    assert run("import", "csv", canonical, "-o", tmp_path / "a.h5").exit_code == 0
    rename = dict(zip(["rx_x", "rx_y", "rx_z", "power_db", "freq_hz"], names))
    header = [rename.get(h, h) for h in HEADER] + (["power_db"] if extra else [])   # a decoy power_db column
    rows = [r + ",999" if extra else r for r in rows_of(links)]
    path = write_csv(tmp_path, rows, header)
    flags = [a for name, src in rename.items() for a in ("--column", f"{name}={src}")]
    result = run("import", "csv", path, "-o", tmp_path / "b.h5", *flags)
    assert result.exit_code == 0, result.stderr
    a, b = read_artifact(tmp_path / "a.h5"), read_artifact(tmp_path / "b.h5")
    for key in ("tx_pos", "rx_pos", "freq_hz", "path_gain_db"):
        np.testing.assert_array_equal(a[key], b[key])


def test_missing_column_names_the_column_flag(tmp_path):
    path = write_csv(tmp_path, ["0,0,1,3,0,1,2.4e9,-50"], HEADER[:-1] + ["rssi"])
    result = run("import", "csv", path, "-o", tmp_path / "m.h5")
    assert_refused(result, 2, "missing required column(s): power_db", "--column power_db=NAME", out=tmp_path / "m.h5")


# ---- unit sanity: each bad-input class ----------------------------------------------------------

@PROPS
@given(links=surveys(min_links=3), tx_dbm=st.floats(25.0, 45.0), pre=st.booleans())
def test_received_dbm_read_as_path_gain_is_refused(tmp_path, links, tx_dbm, pre):
    """Received power of a transmitter of 25..45 dBm (path gains 0..15 dB under free space): 10 dB or more
    above free space at every link."""
    links = [(tx, rx, f, [v + tx_dbm for v in s]) for tx, rx, f, s in links]
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", out)
    if max(v for *_, s in links for v in s) > 10:
        assert_refused(result, 2, "path gain", "--power rssi --tx-power-dbm P", out=out, before=before)
    else:
        assert_refused(result, 2, "above free space", "power_db looks like received power in dBm, not path gain",
                       "--power rssi --tx-power-dbm P", out=out, before=before)
    # the same file with the transmit power stated imports
    assert run("import", "csv", tmp_path / "links.csv", "-o", tmp_path / "ok.h5", "--power", "rssi",
               "--tx-power-dbm", tx_dbm).exit_code == 0


@PROPS
@given(links=surveys(min_links=3), wrong=st.floats(-45.0, -25.0))
def test_wrong_tx_power_is_refused_naming_the_flag(tmp_path, links, wrong):
    """The stated transmit power 25..45 dB too low puts every path gain 10 dB or more above free space."""
    rows = rows_of(links, fmt=lambda pg: f"{pg + 10:.6f}")          # really sent at 10 dBm
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", tmp_path / "m.h5", "--power", "rssi",
                 "--tx-power-dbm", 10 + wrong)
    assert_refused(result, 2, "--tx-power-dbm", out=tmp_path / "m.h5")


@PROPS
@given(links=surveys(min_links=3), unit=st.sampled_from(["mW", "W"]), tx_dbm=st.floats(0.0, 20.0))
def test_linear_power_read_as_db_is_refused(tmp_path, links, unit, tx_dbm):
    scale = {"mW": 0.0, "W": -30.0}[unit]
    rows = rows_of(links, fmt=lambda pg: repr(10 ** ((pg + tx_dbm + scale) / 10)))
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", tmp_path / "m.h5")
    assert_refused(result, 2, "looks like a linear power", "--power-unit mW", out=tmp_path / "m.h5")


@PROPS
@given(value=st.one_of(st.floats(10.5, 500.0), st.floats(-5000.0, -250.5)), pre=st.booleans())
def test_path_gain_outside_a_physical_range_is_refused(tmp_path, value, pre):
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    rows = ["0,0,1,3,0,1,2.4e9,-52", f"0,0,1,0,4,1,2.4e9,{value!r}", "0,0,1,2,2,1,2.4e9,-51"]
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out)
    bound = "above +10 dB" if value > 0 else "below -250 dB"
    assert_refused(result, 2, "line 3: path gain", bound, "--power", "--tx-power-dbm", out=out, before=before)


@PROPS
@given(links=surveys(min_links=3), pre=st.booleans())
def test_centimetre_positions_are_refused_naming_the_unit_flag(tmp_path, links, pre):
    """A room in centimetres: coordinates up to 600, links hundreds of 'metres' long."""
    rows = []
    for tx, rx, f, samples in links:
        rows += [",".join(f"{c * 100:.4f}" for c in (*tx, *rx)) + f",{f:g},{v:.6f}" for v in samples]
    out = tmp_path / "m.h5"
    before = existing_artifact(out) if pre else None
    if not pre and out.exists():
        out.unlink()
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out)
    d = np.median([math.dist(tx, rx) * 100 for tx, rx, *_ in links])
    if d > 100:
        assert_refused(result, 2, "looks like centimetres", "--position-unit cm", out=out, before=before)
    ok = run("import", "csv", tmp_path / "links.csv", "-o", tmp_path / "ok.h5", "--position-unit", "cm")
    assert ok.exit_code == 0, ok.stderr


@PROPS
@given(range_m=st.floats(1.0, 900.0), rcs_dbsm=st.floats(-40.0, 40.0), freq=st.sampled_from([2.4e9, 10e9, 35e9]))
def test_radar_imports_at_long_range_stay_valid(tmp_path, range_m, rcs_dbsm, freq):
    """power = rcs at up to 900 m: path gains far below free space at the radar's own distance are no error."""
    rows = []
    for a in (0, 90, 180, 270):
        phi = math.radians(-a)
        x, y = range_m * math.cos(phi), range_m * math.sin(phi)
        rows.append(f"{x:.6f},{y:.6f},0,{x:.6f},{y:.6f},0.002,{freq:g},{rcs_dbsm:.4f},{a},{range_m!r}")
    out = tmp_path / "m.h5"
    result = run("import", "csv", write_csv(tmp_path, rows, HEADER + ["aspect_deg", "range_m"]), "-o", out,
                 "--power", "rcs")
    assert result.exit_code == 0, result.stderr
    assert validate_artifact(out) == [] and read_artifact(out).attrs["task"] == "rcs"


def test_a_plausible_survey_imports_and_names_its_assumptions(tmp_path):
    links = [((0, 0, 1), (3, 0, 1), 2.4e9, [free_space_db(3, 2.4e9) - 4]),
             ((0, 0, 1), (0, 4, 1), 2.4e9, [free_space_db(4, 2.4e9) + 3])]     # 3 dB over free space: multipath
    result = run("import", "csv", write_csv(tmp_path, rows_of(links)), "-o", tmp_path / "m.h5")
    assert result.exit_code == 0, result.stderr
    assert "positions in metres (--position-unit cm|mm)" in result.stdout
    assert "freq_hz in Hz (--freq-unit" in result.stdout
    result = run("import", "csv", tmp_path / "links.csv", "-o", tmp_path / "m.h5", "--power", "path_gain",
                 "--position-unit", "m", "--freq-unit", "Hz")
    assert "assumed" not in result.stdout


FLAG_SETS = st.lists(st.sampled_from([
    ("--average", "mean-db"), ("--average", "mean-power"), ("--split", "random:0.3"), ("--split", "holdout-tx:1"),
    ("--split", "block:2"), ("--power-unit", "mW"), ("--power-unit", "dBm"), ("--freq-unit", "GHz"),
    ("--position-unit", "cm"), ("--position-scale", "0"), ("--column", "power_db=rssi"), ("--tx-power-dbm", "20"),
    ("--power", "rcs"), ("--split", "block:1:0.5"), ("--column", "rx_x=x"),
]), max_size=4, unique_by=lambda f: f[0])


@PROPS
@given(links=surveys(max_repeats=2), flags=FLAG_SETS, junk=st.sampled_from(["", "0,0,1,3,0,1,2.4e9,abc", "1,2"]))
def test_any_flag_combination_is_a_valid_artifact_or_one_line(tmp_path, links, flags, junk):
    out = tmp_path / "m.h5"
    if out.exists():
        out.unlink()
    rows = rows_of(links) + ([junk] if junk else [])
    result = run("import", "csv", write_csv(tmp_path, rows), "-o", out, *[a for f in flags for a in f])
    assert "Traceback" not in result.stdout + result.stderr and "internal error" not in result.stderr, result.stderr
    if result.exit_code:
        assert_refused(result, result.exit_code, out=out)
        assert result.exit_code in (2, 4)
    else:
        assert validate_artifact(out) == []
