"""`rfir info ARTIFACT`: a readable summary of an artifact; `rfir info --tracer`: the tracer back-end."""
from __future__ import annotations

from typing import Annotated, Optional

import typer
from rich.table import Column, Table

from ..context import console, run_guarded
from rfir_core.errors import ConfigError


def register(app: typer.Typer) -> None:
    app.command("info")(info)


def info(
    ctx: typer.Context,
    artifact: Annotated[Optional[str], typer.Argument(
        metavar="ARTIFACT", help="An rfir artifact (.h5); required unless --tracer.")] = None,
    tracer: Annotated[bool, typer.Option("--tracer", help="Show the ray tracer back-end in use.")] = False,
) -> None:
    """Summarise an artifact: kind, version, producer, provenance, datasets with shapes and units.

    \b
    rfir info ARTIFACT            describe an artifact
    rfir info --tracer            the ray tracer back-end
    rfir info --tracer ARTIFACT   both
    """

    def work():
        if tracer:
            _show_tracer()
        if artifact is None:
            if not tracer:
                raise ConfigError("missing ARTIFACT: `rfir info ARTIFACT` describes an artifact, "
                                  "`rfir info --tracer` the tracer back-end")
            return
        from rfir_core.artifacts import describe_artifact

        summary = describe_artifact(artifact)
        _show(summary)
        _show_materials(artifact)
        if summary["kind"] == "measurements":
            _show_row_counts(artifact)

    run_guarded(ctx, work)


def _show_materials(path: str) -> None:
    """The fitted materials of a physical rf model (datasets material/*), one row each."""
    from rfir_core.artifacts import read_artifact

    art = read_artifact(path)
    if art.kind != "rf" or art.get("material/eps_r") is None:
        return
    names = [str(n) for n in art.free.get("model@attrs", {}).get("material_names", [])]
    # the tabulated material rf-fit took each as (rf_fit.room.tabulated_materials; "": as fitted)
    tabulated = [str(n) for n in art.free.get("model@attrs", {}).get("material_tabulated", [])]
    freqs = art["rf/freq_hz"]
    gam = art["material/gamma_normal_abs"]
    span = art.get("material/gamma_normal_range")   # what the training links allow (rf_fit.physical.reflection_ranges)
    if span is not None:
        from rfir_stages.model.identifiability import range_note
    # names whole, however narrow the terminal (other cells wrap rather than end in "...")
    label = [names[i] if i < len(names) else str(i) for i in range(len(art["material/eps_r"]))]
    table = Table(Column("material", no_wrap=True, min_width=max(map(len, label), default=8)),
                  *(Column(h, overflow="fold") for h in (
                      "eps_r", "sigma(1 GHz) S/m", "S", "thickness mm", *[f"|Gamma(0)| {f / 1e9:g} GHz" for f in freqs],
                      *([] if span is None else [f"|Gamma(0)| range {freqs[0] / 1e9:g} GHz"]),
                      *(["taken as (ITU-R P.2040)"] if any(tabulated) else []))),
                  box=None, pad_edge=False, title="fitted materials")
    for i in range(len(art["material/eps_r"])):
        table.add_row(label[i], f"{art['material/eps_r'][i]:.2f}",
                      f"{art['material/sigma_1ghz_s_per_m'][i]:.3g}", f"{art['material/scattering'][i]:.2f}",
                      f"{1e3 * art['material/thickness_m'][i]:.1f}", *[f"{g:.2f}" for g in gam[i]],
                      *([] if span is None else [f"{span[i][0]:.2f}-{span[i][1]:.2f} {range_note(*span[i])}".strip()]),
                      *([tabulated[i] if i < len(tabulated) else ""] if any(tabulated) else []))
    console.print(table)
    for line in (str(c) for c in art.free.get("model@attrs", {}).get("material_check", []) if str(c)):
        console.print(f"implausible for its surface (rf-fit's check): {line}", highlight=False, markup=False)
    model = art.free.get("model@attrs", {})
    if "antenna_tx" in model:   # the room model's antennas, which weight every path (docs/physics.md 8.10)
        source = str(model.get("antenna_source", ""))
        console.print(f"antennas: tx {model['antenna_tx']}, rx {model.get('antenna_rx', 'isotropic')}"
                      + (f" ({source})" if source else ""), highlight=False, markup=False)
    moved = str(model.get("radio_insets", ""))
    if moved:   # what rf-fit's radio insets and surface depths changed (docs/physics.md 8.10)
        console.print(f"radio insets and surface depths (rf-fit's, kept by validation): {moved}", highlight=False,
                      markup=False)
    terms = str(art.free.get("model@attrs", {}).get("residual_terms", "off"))
    if terms != "off":   # the room model's residual terms in dB (docs/physics.md 8.15)
        console.print(f"residual terms on the physics (rf-fit's choice): {terms}", highlight=False, markup=False)


def _show_row_counts(path: str) -> None:
    """Rows of a measurements artifact per frequency, range and split (what --freq/--range/--split pick)."""
    from rfir_stages.importers.select import row_counts

    from rfir_core.artifacts import read_artifact

    for what, counts in row_counts(read_artifact(path, "measurements")).items():
        console.print(f"  rows per {what}: " + ", ".join(f"{k}: {v}" for k, v in counts.items()),
                      highlight=False, markup=False, soft_wrap=True)


def _show(summary: dict) -> None:
    attrs = summary["attrs"]
    console.print(f"[bold]{summary['path']}[/bold]")
    console.print(f"  kind: {summary['kind']}   schema: {summary['schema_version']}   "
                  f"producer: {attrs.get('producer', '?')}   created: {attrs.get('created', '?')}")
    extra = {k: v for k, v in attrs.items() if k not in ("kind", "schema_version", "producer", "created")}
    if extra:
        console.print("  attributes: " + ", ".join(f"{k}={_short(v)}" for k, v in sorted(extra.items())),
                      highlight=False, markup=False)
    prov = summary["provenance"]
    if prov is not None:
        console.print(f"  provenance: stage={prov.stage} device={prov.device} wall_time={prov.wall_time_s or 0:.1f}s "
                      f"git={prov.git_revision[:12]}", highlight=False)
        for path, digest in prov.inputs.items():
            console.print(f"    input {path}  sha256={digest[:12]}", highlight=False)
    width = max((len(ds["name"]) for ds in summary["datasets"]), default=7)
    table = Table(Column("dataset", no_wrap=True, min_width=width), "shape", "dtype", "unit", "frame",
                  box=None, pad_edge=False)
    for ds in summary["datasets"]:
        table.add_row(ds["name"], "x".join(str(s) for s in ds["shape"]) or "scalar", ds["dtype"], ds["unit"], ds["frame"])
    console.print(table)


def _short(value) -> str:
    """An attribute value in one short piece (long arrays as a count and the first items)."""
    if hasattr(value, "__len__") and not isinstance(value, str) and len(value) > 4:
        head = ", ".join(str(v) for v in list(value)[:3])
        return f"[{head}, ... ({len(value)} items)]"
    return str(value)


def _show_tracer() -> None:
    try:
        import rfir_tracer
    except ImportError as exc:
        raise ConfigError(f"the tracer extension is not importable ({exc}); re-run `make setup`") from None
    details = rfir_tracer.backend_info()
    console.print("tracer: " + ", ".join(f"{k}={v}" for k, v in details.items()), highlight=False)
