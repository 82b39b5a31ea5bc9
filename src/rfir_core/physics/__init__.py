"""The physics layer: pure functions (numpy/torch), SI units, units in argument names; imports nothing of rfir above it.
See docs/physics.md. One definition of each term, which every model and simulator imports:

- `closed_forms`: C0, wavelength, wavenumber, dB, Friis and the RCS closed forms;
- `materials`: the ITU-R P.2040 material laws (one dispersion law `power_law`, one metal `METAL_SIGMA_S_PER_M`),
  Fresnel half-space and slab coefficients, the specular share sqrt(1 - S^2);
- `polarisation`: the V/H antenna convention (Sionna RT's theta-hat / phi-hat) and the TE/TM basis of a reflection;
- `angle_nodes`: tables over the incidence angle and their interpolation;
- `crossings`: what a straight leg crosses (the tracer's hits away from its ends; planar patches crossed);
- `antennas`: the horn and omni patterns of the simulator (the fitter's patterns reuse them);
- `gaussian_rf`: the geometry of a 3D Gaussian.
"""
from .closed_forms import (C0, db_to_power, friis_path_gain, plate_image_echo_gain, plate_rcs_broadside_m2,
                           power_to_db, rcs_from_path_gain, sphere_rcs_m2, wavelength_m, wavenumber)

__all__ = ["C0", "db_to_power", "friis_path_gain", "plate_image_echo_gain", "plate_rcs_broadside_m2",
           "power_to_db", "rcs_from_path_gain", "sphere_rcs_m2", "wavelength_m", "wavenumber"]
