"""Choose the acceleration structure for a triangle set: brute force or a BVH.

A small scene is intersected fastest by testing every triangle (one fused loop, no
gathers, no divergence); a large one needs a BVH. :func:`build_geometry` picks between them
from the triangle count, with the crossover measured on this machine class (see
benchmarks/README.md#bvh-crossover).
"""

from __future__ import annotations

import numpy as np

from jaxrt.geometry.bvh import BVH, build_bvh
from jaxrt.geometry.triangle import TriangleSet, triangle_set

# Brute force is faster below this many triangles (2-core CPU, with the BVH's ray compaction:
# incoherent rays cross over between 80 and 192 triangles, ≈ 90 by log-log interpolation;
# benchmarks/crossover.py, benchmarks/README.md#bvh-crossover).
AUTO_BVH_THRESHOLD = 96


def build_geometry(triangles, accel: str = "auto", **bvh_options) -> TriangleSet | BVH:
    """Pack ``triangles`` (F, 3, 3) for intersection, as a ``TriangleSet`` or a ``BVH``.

    Both plug into ``jaxrt.geometry.triangle.closest_hit`` / ``any_hit`` for ONE ray (vmap-able).

    Args:
        triangles: (F, 3, 3) finite vertices, world space.
        accel: ``"brute"`` (every triangle per ray, cost ∝ F), ``"bvh"`` (binned-SAH BVH,
            cost ∝ log F after an O(F log F) host build), or ``"auto"``: brute force when
            ``F < AUTO_BVH_THRESHOLD`` (= 96, the measured crossover for incoherent rays),
            the BVH otherwise.
        **bvh_options: ``leaf_size``, ``n_bins`` for :func:`jaxrt.geometry.bvh.build_bvh`.
    Returns:
        A ``TriangleSet`` or a ``BVH``.
    Raises:
        ValueError: unknown ``accel``, options given for brute force, or bad triangles.
    """
    if accel not in ("auto", "brute", "bvh"):
        raise ValueError(f"unknown accel {accel!r}: expected 'auto', 'brute' or 'bvh'")
    n_tri = int(np.shape(triangles)[0]) if np.ndim(triangles) == 3 else -1
    if accel == "auto":
        accel = "brute" if 0 <= n_tri < AUTO_BVH_THRESHOLD else "bvh"
    if accel == "brute":
        if bvh_options:
            raise ValueError(f"BVH options {sorted(bvh_options)} given for brute force")
        return triangle_set(triangles)
    return build_bvh(triangles, **bvh_options)
