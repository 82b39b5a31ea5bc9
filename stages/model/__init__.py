"""rfir's physical radio model: materials with physical parameters on surfel Gaussians.

- `materials`: ITU-R P.2040 material laws, Fresnel half-space and slab coefficients (docs/physics.md
  section 8). The one definition of each; the physical-optics simulator (rfir_stages.po) uses them too.
- `surfels`: geometry-only quantities of surfels (area by partition of unity, footprint).
- `physical`: the forward model (coherent specular physical optics + diffuse power) and its
  learnable material parameters.
- `fit_physical`: fitting those parameters to measured path gains.
"""
