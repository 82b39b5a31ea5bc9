"""`rfir geom CALIB -o SCENE`: 3D Gaussians with normals trained on calibrated photos."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, console, err_console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("geom")(geom)


def geom(
    ctx: typer.Context,
    calib: Annotated[Path, typer.Argument(help="Calibration artifact (calib.h5 from `rfir calibrate`).")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="FILE", help="Scene artifact to write (.h5).")] = Path("scene.h5"),
    iterations: Annotated[Optional[int], typer.Option("--iterations", metavar="N",
            help="Training steps (geom.iterations).")] = None,
    width: Annotated[Optional[int], typer.Option("--width", metavar="PX",
            help="Training image width in px (geom.max_image_width).")] = None,
    gt_mesh: Annotated[Optional[Path], typer.Option(
        "--gt-mesh", metavar="FILE", help="Ground-truth mesh (.ply) for the normal and Chamfer metrics (default: auto).")] = None,
    checkpoint: Annotated[Optional[Path], typer.Option(
        "--checkpoint", metavar="FILE", help="Checkpoint file (default: OUT.ckpt.pt).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue from the checkpoint when it exists.")] = False,
) -> None:
    """Train Gaussians with normals on calibrated photos; write SCENE.h5, SCENE.ply, SCENE_mesh.ply, SCENE_renders/."""
    opts = options(ctx)

    def work():
        from rfir_stages.geom.stage import run, side_paths

        from rfir_core.artifacts import check_output

        # before any training: no output (the artifact, SCENE.ply, SCENE_mesh.ply) over an input or another kind
        check_output(out, "scene", inputs=[calib, gt_mesh])
        for side in side_paths(Path(out))[:2]:
            check_output(side, None, inputs=[calib, gt_mesh])
        table = dict(opts.config().get("geom", {}))
        if iterations is not None:
            table["iterations"] = int(iterations)
        if width is not None:
            table["max_image_width"] = int(width)
        if gt_mesh is not None:
            table["evaluate"] = {**table.get("evaluate", {}), "gt_mesh": str(gt_mesh)}
        device = opts.torch_device()
        with RichReporter(opts.verbosity) as reporter:
            return run(calib, out, table, seed=opts.seed, device=device, config_toml=opts.config_toml(),
                       progress=reporter, checkpoint=checkpoint, resume=resume)

    r = run_guarded(ctx, work)
    _summary(r, opts.verbosity)


def _summary(r, verbosity: int) -> None:
    m = r.metrics
    for note in r.notes:
        err_console.print(f"[yellow]warning:[/yellow] {note}", highlight=False, soft_wrap=True)
    if r.resumed_at:
        console.print(f"resumed from the checkpoint at step {r.resumed_at}", highlight=False)
    table = Table(title="geom: held-out metrics", box=None, pad_edge=False, show_header=False)
    table.add_column("what", style="bold")
    table.add_column("value")
    table.add_row("views", f"{r.num_train_views} train + {r.num_test_views} held out at {r.image_size[0]} x "
                           f"{r.image_size[1]} px")
    table.add_row("Gaussians", f"{r.num_init} from sparse points -> {r.num_gaussians}")
    if "psnr_db" in m:
        table.add_row("PSNR / SSIM", f"{m['psnr_db']:.2f} dB / {m['ssim']:.4f}")
    if "normal_error_deg_mean" in m:
        table.add_row("normal error (pixels)", f"mean {m['normal_error_deg_mean']:.1f} deg, median "
                                               f"{m['normal_error_deg_median']:.1f} deg")
        if "normal_error_flat_deg_median" in m:
            table.add_row("  away from edges", f"mean {m['normal_error_flat_deg_mean']:.1f} deg, median "
                                               f"{m['normal_error_flat_deg_median']:.1f} deg "
                                               f"({m['flat_pixel_fraction']:.0%} of the pixels)")
        table.add_row("depth error (median)", f"{m['depth_error_m_median'] * 1000:.2f} mm")
    if "gaussian_normal_error_deg_mean" in m:
        table.add_row("normal error (Gaussians)", f"mean {m['gaussian_normal_error_deg_mean']:.1f} deg, median "
                                                  f"{m['gaussian_normal_error_deg_median']:.1f} deg; "
                                                  f"{m['gaussian_normal_same_side_fraction']:.0%} on the mesh normal's side")
    if "chamfer_m" in m:
        table.add_row("Chamfer (fused mesh)", f"{m['chamfer_m'] * 1000:.2f} mm (accuracy {m['mesh_accuracy_m'] * 1000:.2f}"
                                              f", completeness {m['mesh_completeness_m'] * 1000:.2f} mm)")
    if "chamfer_visible_m" in m:
        table.add_row("Chamfer (visible truth)", f"{m['chamfer_visible_m'] * 1000:.2f} mm = "
                                                 f"{100 * m['chamfer_visible_m'] / m['gt_extent_m']:.2f} % of the "
                                                 f"{m['gt_extent_m']:.2f} m extent (completeness "
                                                 f"{m['mesh_completeness_visible_m'] * 1000:.2f} mm; "
                                                 f"{m['gt_visible_fraction']:.0%} of the truth is seen)")
    if r.gt_mesh is not None:
        table.add_row("ground truth", str(r.gt_mesh))
    table.add_row("time", " + ".join(f"{k} {v:.1f}s" for k, v in r.timings_s.items() if k != "total")
                  + f" = {r.timings_s.get('total', 0.0):.1f}s")
    console.print(table)
    side = [str(p) for p in (r.ply_path, r.mesh_path, r.renders_dir) if p is not None]
    console.print(f"[green]wrote[/green] {r.path}" + (f" and {', '.join(side)}" if side else ""), highlight=False)
