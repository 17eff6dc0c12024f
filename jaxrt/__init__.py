"""jaxrt: batched Monte Carlo estimators for physically based rendering in JAX.

The package mirrors the rendering pipeline (samples → warps → rays → intersections →
shading → estimators → render → files); see README.md for a tour.
"""

__version__ = "0.1.0"
