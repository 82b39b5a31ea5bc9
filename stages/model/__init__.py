"""rfir's physical radio model: materials with physical parameters on surfel Gaussians.

- the material laws, Fresnel and slab coefficients, polarisation bases and angle tables it uses are the physics
  layer's (rfir_core.physics; docs/physics.md section 8), shared with the simulators.
- `link_set`, `links`, `occlusion`, `antenna_patterns`, `split_protocols`, `validation_folds`, `crossings`: the
  links, the visibility tracer, the antennas, the train/test protocols and the crossing counts that the model and
  the stages above it (rf_fit, predict, diagnose, simulate) share.
- `surfels`: geometry-only quantities of surfels (area by partition of unity, footprint).
- `physical`: the forward model (coherent specular physical optics + diffuse power) and its
  learnable material parameters.
- `fit_physical`: fitting those parameters to measured path gains.
"""
