"""The radio version of a scene: Mitsuba XML + binary PLY per object, loaded into Sionna RT.

Sionna and Mitsuba are imported lazily (inside functions), so the rest of the package works
without them. Variant: `llvm_ad_mono_polarized` (CPU) unless a variant is already set.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from .scenes import SceneSpec, write_ply

C0 = 299_792_458.0  # m/s, exact (3e8 gives a 0.006 dB offset, SIONNA-NOTES)


@dataclass(frozen=True)
class MaterialEffects:
    """Surface-level switches applied to every radio material after loading.

    scattering_coefficient: S in [0, 1]; share of reflected energy scattered diffusely
        (only used when the solver runs with diffuse reflection on).
    scattering_pattern: "lambertian", "directive" or "backscattering".
    alpha_r: lobe exponent of the directive/backscattering pattern (integer >= 1).
    """

    scattering_coefficient: float = 0.0
    scattering_pattern: str = "directive"
    alpha_r: int = 4


def write_radio_xml(spec: SceneSpec, folder) -> Path:
    """Write <folder>/<scene>.xml and <folder>/meshes/<object>.ply; return the XML path."""
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    lines = ['<scene version="2.1.0">']
    materials = {}
    for o in spec.objects:  # one radio material per (ITU type, thickness)
        materials.setdefault((o.radio_material, o.thickness_m),
                             f"itu-{o.radio_material}-{round(o.thickness_m * 1e6)}um")
    for (itu, thick), mat_id in materials.items():
        lines += [
            f'  <bsdf type="itu-radio-material" id={quoteattr(mat_id)}>',
            f'    <string name="type" value={quoteattr(itu)}/>',
            f'    <float name="thickness" value="{thick:.6g}"/>',
            '  </bsdf>',
        ]
    for o in spec.objects:
        write_ply(folder / "meshes" / f"{o.name}.ply", o.vertices, o.faces)
        mat_id = materials[(o.radio_material, o.thickness_m)]
        lines += [
            f'  <shape type="ply" id={quoteattr(o.name)}>',
            f'    <string name="filename" value={quoteattr("meshes/" + o.name + ".ply")}/>',
            '    <boolean name="face_normals" value="true"/>',
            f'    <ref id={quoteattr(mat_id)} name="bsdf"/>',
            '  </shape>',
        ]
    lines.append("</scene>")
    path = folder / f"{spec.name}.xml"
    path.write_text("\n".join(lines) + "\n")
    return path


def set_variant() -> None:
    import mitsuba as mi

    if mi.variant() is None or "polarized" not in str(mi.variant()):
        mi.set_variant("llvm_ad_mono_polarized")


def load_radio_scene(spec: SceneSpec, folder, frequency_hz: float, effects: MaterialEffects = MaterialEffects()):
    """Export `spec` to `folder` and load it into Sionna RT with isotropic V-polarised antennas.

    Returns a `sionna.rt.Scene`. Antenna patterns (horn) are applied afterwards per path, in
    numpy (see `antennas`), so the simulator and the fitter share one pattern function.
    An empty spec gives Sionna's empty scene.
    """
    if spec.objects:
        return load_radio_xml(write_radio_xml(spec, folder), frequency_hz, effects)
    return load_radio_xml(None, frequency_hz, effects)


def load_radio_xml(xml_path, frequency_hz: float, effects: MaterialEffects = MaterialEffects()):
    """Load an XML written by `write_radio_xml` (None: Sionna's empty scene) as `load_radio_scene`
    does; used by worker processes, which load the parent's exported scene."""
    set_variant()
    import sionna.rt as rt

    scene = rt.load_scene(str(xml_path), merge_shapes=False) if xml_path is not None else rt.load_scene()
    scene.frequency = float(frequency_hz)
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    apply_material_effects(scene, effects)
    return scene


def apply_material_effects(scene, effects: MaterialEffects) -> None:
    import sionna.rt as rt

    for mat in scene.radio_materials.values():
        if not hasattr(mat, "scattering_coefficient"):
            continue
        mat.scattering_coefficient = float(effects.scattering_coefficient)
        if effects.scattering_pattern == "lambertian":
            mat.scattering_pattern = rt.LambertianPattern()
        elif effects.scattering_pattern == "directive":
            mat.scattering_pattern = rt.DirectivePattern(alpha_r=int(effects.alpha_r))
        elif effects.scattering_pattern == "backscattering":
            mat.scattering_pattern = rt.BackscatteringPattern(alpha_r=int(effects.alpha_r),
                                                              alpha_i=int(effects.alpha_r), lambda_=0.5)
        else:
            raise ValueError(f"unknown scattering pattern {effects.scattering_pattern!r} "
                             "(known: lambertian, directive, backscattering)")


def set_devices(scene, tx_pos, rx_pos) -> None:
    """Replace all transmitters and receivers: tx_pos (T, 3), rx_pos (R, 3) in metres."""
    import sionna.rt as rt

    for name in list(scene.transmitters):
        scene.remove(name)
    for name in list(scene.receivers):
        scene.remove(name)
    for i, p in enumerate(tx_pos):
        scene.add(rt.Transmitter(name=f"tx{i}", position=[float(x) for x in p], display_radius=0.01))
    for i, p in enumerate(rx_pos):
        scene.add(rt.Receiver(name=f"rx{i}", position=[float(x) for x in p], display_radius=0.01))
