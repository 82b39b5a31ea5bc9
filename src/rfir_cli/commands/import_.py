"""`rfir import csv FILE` and `rfir import nerf2-ble DIR`: real measurements into a measurements artifact."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape

from ..context import console, options, run_guarded
from rfir_core.text import plural

import_app = typer.Typer(help="Bring real measurements in (CSV links, NeRF2 BLE).", no_args_is_help=True,
                         rich_markup_mode=None)


def register(app: typer.Typer) -> None:
    app.add_typer(import_app, name="import")


Out = Annotated[Path, typer.Option("-o", "--out", help="Measurements artifact to write (.h5).")]
Scale = Annotated[float, typer.Option("--position-scale", help="Multiply coordinates by this (0.001 for mm).")]


def _given(ctx: typer.Context, name: str) -> bool:
    """Whether option `name` was stated (command line or environment), not left at its default."""
    source = ctx.get_parameter_source(name)
    return source is not None and getattr(source, "name", "") not in ("DEFAULT", "DEFAULT_MAP")


def _report(result) -> None:
    for note in result.notes:
        console.print(note, highlight=False, markup=False, emoji=False, soft_wrap=True)
    console.print(f"[green]wrote[/green] {escape(str(result.path))}: {plural(result.links, 'link')} x "
                  f"{plural(result.freqs, 'frequency')}, task {result.task}", highlight=False, emoji=False)


@import_app.command("csv")
def import_csv_command(
    ctx: typer.Context,
    file: Annotated[Path, typer.Argument(help="CSV with tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db[,...].")],
    out: Out,
    scene: Annotated[str, typer.Option("--scene", help="Scene name recorded in the artifact.")] = "imported",
    tx_power_dbm: Annotated[Optional[float], typer.Option(
        "--tx-power-dbm", help="Transmit power in dBm: power_db is received dBm (power = rssi).")] = None,
    position_scale: Scale = 1.0,
    antenna: Annotated[Optional[str], typer.Option(
        "--antenna", help="Both antennas: isotropic, dipole[:AX,AY,AZ], horn:HPBW_DEG or table:FILE, a horn's or "
        "table's boresight after @AX,AY,AZ (default +z).")] = None,
    antenna_tx: Annotated[Optional[str], typer.Option("--antenna-tx", help="Transmit antenna (as --antenna).")] = None,
    antenna_rx: Annotated[Optional[str], typer.Option("--antenna-rx", help="Receive antenna (as --antenna).")] = None,
    polarisation: Annotated[Optional[str], typer.Option("--polarisation", help="V or H.")] = None,
    power: Annotated[Optional[str], typer.Option(
        "--power", help="What power_db holds: path_gain (dB), rcs (dBsm) or rssi (dBm, with --tx-power-dbm).")] = None,
    task: Annotated[Optional[str], typer.Option(
        "--task", help="rcs, wideband or rssi instead of the detected task (rule in docs/artifacts.md).")] = None,
    average: Annotated[Optional[str], typer.Option(
        "--average", metavar="mean-db|mean-power",
        help="Average repeated rows of one link and frequency (their dB values, or their linear powers); the rows "
             "per link and their spread are stored (sample_count, sample_std_db). Without it they are refused.")] = None,
    split: Annotated[Optional[str], typer.Option(
        "--split", metavar="PROTOCOL",
        help="Write a train/test split (uses the global --seed): random:SHARE (any task), holdout-tx:N or "
             "holdout-rx:N (rssi task: N transmitters or receivers held out), block:SIZE[:SHARE] or "
             "block-tx:SIZE[:SHARE] (rssi task: receiver or transmitter squares of SIZE metres held out, SHARE of "
             "the links, default 0.2). Refused when the file has a split column.")] = None,
    power_unit: Annotated[Optional[str], typer.Option(
        "--power-unit", metavar="dB|dBm|mW|W",
        help="Unit of power_db: dB (default; its meaning is --power), or received power in dBm, mW or W "
             "(power rssi, needs --tx-power-dbm; mW and W are converted to dBm).")] = None,
    freq_unit: Annotated[Optional[str], typer.Option(
        "--freq-unit", metavar="Hz|kHz|MHz|GHz", help="Unit of the freq_hz column (default Hz).")] = None,
    position_unit: Annotated[Optional[str], typer.Option(
        "--position-unit", metavar="m|cm|mm",
        help="Unit of coordinates and ranges (default m); the same as --position-scale 1, 0.01 or 0.001.")] = None,
    column: Annotated[Optional[list[str]], typer.Option(
        "--column", metavar="NAME=CSVNAME",
        help="Read rfir's column NAME from the file's column CSVNAME (repeatable), e.g. --column power_db=rssi "
             "--column rx_x=x.")] = None,
) -> None:
    """Import links from a CSV file (columns and set-up options: docs/artifacts.md).

    The set-up comes from these flags, else a TOML beside the CSV (same stem), else '# key = value'
    lines at the top of the CSV. Units that look wrong (path gain above free space, centimetres,
    linear powers) are refused with the flag that fixes them."""
    from rfir_stages.importers import import_csv

    opts = options(ctx)
    scale_given = _given(ctx, "position_scale")
    result = run_guarded(ctx, lambda: import_csv(file, out, scene=scene, tx_power_dbm=tx_power_dbm,
                                                 position_scale=position_scale, config_toml=opts.config_toml(),
                                                 antenna=antenna, antenna_tx=antenna_tx, antenna_rx=antenna_rx,
                                                 polarisation=polarisation, power=power, task=task,
                                                 average=average, split=split, seed=opts.seed, power_unit=power_unit,
                                                 freq_unit=freq_unit, position_unit=position_unit, columns=column,
                                                 position_scale_given=scale_given))
    _report(result)


@import_app.command("nerf2-ble")
def import_nerf2_command(
    ctx: typer.Context,
    folder: Annotated[Path, typer.Argument(help="Folder with gateway_position.yml, tx_pos.csv, gateway_rssi.csv.")],
    out: Out,
    freq_hz: Annotated[float, typer.Option("--freq-hz", help="Carrier frequency [Hz].")] = 2.4e9,
    tx_power_dbm: Annotated[float, typer.Option("--tx-power-dbm", help="Beacon transmit power [dBm].")] = 0.0,
    position_scale: Scale = 1.0,
    position_unit: Annotated[Optional[str], typer.Option(
        "--position-unit", metavar="m|cm|mm", help="Unit of the positions (default m); as --position-scale.")] = None,
) -> None:
    """Import NeRF2's BLE data set layout (RSSI -100 dBm = not received, dropped)."""
    from rfir_stages.importers import import_nerf2_ble
    from rfir_stages.importers.units import resolve_units

    opts = options(ctx)
    given = _given(ctx, "position_scale")
    result = run_guarded(ctx, lambda: import_nerf2_ble(
        folder, out, freq_hz=freq_hz, tx_power_dbm=tx_power_dbm, config_toml=opts.config_toml(),
        position_scale=resolve_units(position_unit=position_unit,
                                     position_scale=position_scale if given else None).position_scale))
    _report(result)
