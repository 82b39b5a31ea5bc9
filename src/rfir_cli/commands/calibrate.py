"""`rfir calibrate IMAGES/ -o calib.h5`: camera poses from photos (pycolmap), in metres, in the scene frame."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, console, err_console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("calibrate")(calibrate)


def calibrate(
    ctx: typer.Context,
    images: Annotated[Path, typer.Argument(help="Folder of photos (one camera, all the same size).")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="FILE",
            help="Calibration artifact to write (.h5).")] = Path("calib.h5"),
    poses: Annotated[Optional[Path], typer.Option(
        "--poses", metavar="FILE",
                help="Known camera centres: a `cameras` artifact (.h5, from simulate) or a name,x,y,z CSV.")] = None,
    points: Annotated[Optional[Path], typer.Option(
        "--points", metavar="CSV", help="Known 3D points: CSV of label,x,y,z,image,u,v (one line per observation).")] = None,
    markers: Annotated[Optional[Path], typer.Option(
        "--markers", metavar="CSV", help="ArUco marker layout: CSV of id,size_m,x,y,z,yaw_deg (markers lying flat).")] = None,
    subset: Annotated[Optional[int], typer.Option(
        "--subset", metavar="N", help="Use only this many --poses references, evenly spread (0: all).")] = None,
    intrinsics_from: Annotated[Optional[Path], typer.Option(
        "--intrinsics-from", metavar="FILE", help="A `cameras` artifact whose shared intrinsics are known and kept fixed.")] = None,
    colmap_model: Annotated[Optional[Path], typer.Option(
        "--colmap-model", metavar="DIR", help="Import this COLMAP sparse model instead of running SfM.")] = None,
    no_metric: Annotated[bool, typer.Option(
        "--no-metric", help="Allow an artifact without metric scale (arbitrary SfM frame).")] = False,
) -> None:
    """Calibrate photos: SfM (or an imported COLMAP model), metric alignment, calib.h5 and a top-view PNG."""
    from rfir_stages.calibrate import CalibrateInputs, CalibrateOptions, run

    opts = options(ctx)

    def work():
        from rfir_core.artifacts import check_output

        # before SfM: the artifact replaces neither an input nor a file of another kind (without --force)
        check_output(out, "calib", inputs=[poses, points, markers, intrinsics_from])
        config = opts.config()
        calib_options = CalibrateOptions.from_config(config.get("calibrate", {}), seed=opts.seed)
        inputs = CalibrateInputs(images, out, poses=poses, points=points, markers=markers,
                                 intrinsics_from=intrinsics_from, colmap_model=colmap_model, no_metric=no_metric,
                                 subset=subset)
        with RichReporter(opts.verbosity) as reporter:
            return run(inputs, calib_options, reporter, config_toml=opts.config_toml())

    result = run_guarded(ctx, work)
    _summary(result, opts.verbosity)


def _summary(result, verbosity: int) -> None:
    for warning in result.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {warning}", highlight=False, soft_wrap=True)
    table = Table(title="calibration", box=None, pad_edge=False, show_header=False)
    table.add_column("what", style="bold")
    table.add_column("value")
    table.add_row("registered images", f"{result.n_registered} / {result.n_images} ({result.registered_fraction:.0%})")
    if result.unregistered:
        shown = ", ".join(result.unregistered[:5]) + (" ..." if len(result.unregistered) > 5 else "")
        table.add_row("not registered", shown)
    table.add_row("mean reprojection error", f"{result.mean_reproj_px:.3f} px")
    table.add_row("sparse points", str(result.n_points))
    table.add_row("camera model", result.camera_model)
    if result.alignment is not None:
        res = result.alignment.residuals_m
        inl = result.alignment.inliers
        table.add_row("alignment", f"{result.alignment.method}; {int(inl.sum())}/{len(inl)} references, "
                                   f"scale {result.alignment.scale:.4g}")
        table.add_row("alignment error", f"mean {res[inl].mean() * 100:.2f} cm, max {res[inl].max() * 100:.2f} cm")
    else:
        table.add_row("alignment", "[yellow]none: arbitrary SfM units (--no-metric)[/yellow]")
    table.add_row("time", " + ".join(f"{k} {v:.1f}s" for k, v in result.timings_s.items() if k != "total")
                  + f" = {result.timings_s.get('total', 0.0):.1f}s")
    if verbosity >= 0:
        console.print(table)
    console.print(f"[green]wrote[/green] {result.out}" + (f" and {result.plot_path}" if result.plot_path else ""),
                  highlight=False)
