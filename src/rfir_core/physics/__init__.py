"""Pure physics functions (numpy/torch), SI units, units in argument names. See docs/physics.md."""
from .closed_forms import (C0, db_to_power, friis_path_gain, plate_image_echo_gain, plate_rcs_broadside_m2,
                           power_to_db, rcs_from_path_gain, sphere_rcs_m2, wavelength_m, wavenumber)

__all__ = ["C0", "db_to_power", "friis_path_gain", "plate_image_echo_gain", "plate_rcs_broadside_m2",
           "power_to_db", "rcs_from_path_gain", "sphere_rcs_m2", "wavelength_m", "wavenumber"]
