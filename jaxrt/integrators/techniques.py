"""The technique registry: which function shades a camera sample for each estimator.

:data:`TECHNIQUES` maps every name of :data:`~jaxrt.integrators.config.ESTIMATORS` to its
:class:`Technique`: the function that estimates the light reflected at one shading point
(the direct techniques of :mod:`jaxrt.integrators.direct`, the path tracer of
:mod:`jaxrt.integrators.path`) and how many random dimensions one camera sample uses.
:func:`shade`, :func:`num_dims` and the render passes look estimators up here, never by
testing their names. :func:`camera_sample` is one camera sample: the camera ray, its first
hit, the emission seen there plus the technique's estimate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxrt.integrators.config import Estimator
from jaxrt.integrators.direct import DIRECT_TECHNIQUES
from jaxrt.integrators.path import path, path_dims, vertex_dims
from jaxrt.integrators.ris import ris_dims
from jaxrt.integrators.terms import Stream, camera_ray, shading_point
from jaxrt.scene.container import Scene
from jaxrt.scene.queries import TRIANGLE, SurfaceHit, emitted, intersect


class Technique(NamedTuple):
    """An estimator's shading function and its random dimensions per camera sample."""

    shade: Callable  # (scene, est, ShadingPoint, Stream) -> (3,) radiance
    dims: Callable[[Estimator], int | None]  # dimensions used (None: unbounded)
    #: paths of unequal length: the passes regenerate and compact lanes (jaxrt.integrators.path)
    regenerates: bool = False


def _direct_dims(est: Estimator) -> int:
    if est.name == "mis":
        return 2 + 4 * est.light_samples + 2 * est.bsdf_samples
    if est.name == "mis_one_sample":
        return 10
    if est.name == "ris":
        return ris_dims(est.ris_candidates)
    return 2 + 4


#: name → :class:`Technique`, for every estimator
TECHNIQUES: dict[str, Technique] = {
    **{name: Technique(fn, _direct_dims) for name, fn in DIRECT_TECHNIQUES.items()},
    "path": Technique(path, lambda est: path_dims(est.max_depth, vertex_dims(est)),
                      regenerates=True),
}


def num_dims(est: Estimator) -> int | None:
    """How many random dimensions one camera sample of ``est`` uses (None: unbounded)."""
    return TECHNIQUES[est.name].dims(est)


def shade(scene: Scene, est: Estimator, hit: SurfaceHit, wo: Array, s: Stream) -> Array:
    """Radiance reflected at ``hit`` towards ``wo`` (0 off triangle surfaces): direct
    illumination, or for ``path`` all the light of paths up to ``max_depth`` segments."""
    x = shading_point(scene, hit, wo)
    technique = TECHNIQUES[est.name].shade
    value = technique(scene, est, x, s)
    return jnp.where(hit.kind == TRIANGLE, value, 0)


def camera_sample(scene: Scene, est: Estimator, pixel: Array, index: Array, seed: Array,
                  sampler: str = "independent", spp: int = 1) -> Array:
    """Radiance (3,) of camera sample ``index`` of flat pixel ``pixel`` (row-major, row 0 top).

    ``L = L_e(first hit, −d) + L_direct(first hit, −d)``: emitters seen by the camera add
    their own radiance; surfaces add the estimator's direct illumination.
    """
    s = Stream.of(sampler, seed, pixel, index, spp)
    hit, wo = camera_hit(scene, pixel, s)
    return camera_radiance(scene, est, hit, wo, s)


def camera_hit(scene: Scene, pixel: Array, s: Stream) -> tuple[SurfaceHit, Array]:
    """The first half of :func:`camera_sample`: the camera ray's first hit and ``wo = −d``."""
    o, d = camera_ray(scene, pixel, s)
    # every camera ray starts at the eye: triangles are tested by their planes through it
    return intersect(scene, o, d, jnp.asarray(jnp.inf, o.dtype), shared_origin=True), -d


def camera_radiance(scene: Scene, est: Estimator, hit: SurfaceHit, wo: Array,
                    s: Stream) -> Array:
    """The second half of :func:`camera_sample`: ``L_e(hit, wo)`` plus the estimator's
    direct illumination at the hit (3,)."""
    return emitted(scene, hit, wo) + shade(scene, est, hit, wo, s)
