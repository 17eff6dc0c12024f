"""Which estimator a render runs: its name and static parameters, validated before any work.

:class:`Estimator` is hashable (it selects the compiled program); :func:`make_estimator`
builds one from a name and keyword parameters and raises ``ValueError`` for anything that
does not make sense; :func:`prepare_scene` switches triangle lights to the measure an
estimator forces.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxrt.scene.container import Scene, with_triangle_sampling

#: The estimators of the reflection equation (direct illumination): on one scene they all
#: estimate the same image.
DIRECT_ESTIMATORS = ("uniform_hemisphere", "cosine_hemisphere", "bsdf", "light_area",
                     "light_solid_angle", "mis", "mis_one_sample", "ris")
#: Every estimator: the direct ones and the path tracer (global illumination,
#: jaxrt.integrators.path).
ESTIMATORS = DIRECT_ESTIMATORS + ("path",)
HEURISTICS = ("balance", "power")
#: The path tracer's next-event estimators (Estimator.nee).
NEE = ("light", "ris")


class Estimator(NamedTuple):
    """Static configuration of an estimator (hashable: it selects the compiled program).

    name: one of :data:`ESTIMATORS`; light_samples, bsdf_samples: sample counts of the
    multi-sample MIS estimator; heuristic: "balance" | "power" (MIS and the path tracer);
    light_prob: probability of choosing light sampling in one-sample MIS; max_depth,
    rr_depth: the path tracer's longest path in segments (−1: unbounded) and the depth from
    which Russian roulette ends paths (:mod:`jaxrt.integrators.path`, Mitsuba 3's convention);
    ris_candidates: the light samples RIS resamples from (:mod:`jaxrt.integrators.ris`);
    nee: the path tracer's next-event estimation, "light" (one light sample) or "ris"
    (``ris_candidates`` light samples resampled, one shadow ray, MIS-weighted against the
    BSDF sample).
    """

    name: str = "mis"
    light_samples: int = 1
    bsdf_samples: int = 1
    heuristic: str = "power"
    light_prob: float = 0.5
    max_depth: int = -1
    rr_depth: int = 5
    ris_candidates: int = 8
    nee: str = "light"

    @property
    def triangle_sampling(self) -> str | None:
        """How this estimator forces triangle lights to be sampled, or None: the scene decides.

        ``light_area`` and ``light_solid_angle`` *are* the two measures of light sampling, so
        they set it; every other estimator samples triangle lights as the scene's light table
        says (``build_scene(triangle_sampling=...)``).
        """
        return {"light_area": "area", "light_solid_angle": "solid_angle"}.get(self.name)



def prepare_scene(scene: Scene, est: Estimator) -> Scene:
    """The scene as ``est`` samples it: triangle lights switched to the measure the estimator
    forces (only the static structure changes, no array is copied); unchanged otherwise."""
    if est.triangle_sampling is None:
        return scene
    # the same lights (only how triangles are sampled changes): the same shadow-ray triangles
    return scene.replace(lights=with_triangle_sampling(scene.lights, est.triangle_sampling),
                         occluders=scene.occluders)


def make_estimator(estimator: str | Estimator = "mis", **params) -> Estimator:
    """Validate and build an :class:`Estimator` from a name and parameters.

    Raises ValueError for unknown names or heuristics, negative sample counts, MIS without
    any sample, ``light_prob`` outside (0, 1), a path depth that is neither −1 nor ≥ 1, an
    ``rr_depth`` < 1, path-tracer options given to a direct estimator, or sample counts
    other than 1 given to the path tracer (one light and one BSDF sample per vertex).
    """
    est = estimator if isinstance(estimator, Estimator) else Estimator(name=estimator)
    est = est._replace(**params)
    if est.name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {est.name!r}; choose one of {', '.join(ESTIMATORS)}")
    if est.heuristic not in HEURISTICS:
        raise ValueError(f"unknown MIS heuristic {est.heuristic!r}; choose 'balance' or 'power'")
    for field in ("light_samples", "bsdf_samples"):
        v = getattr(est, field)
        if not isinstance(v, int) or v < 0:
            raise ValueError(f"{field} must be an integer >= 0, got {v!r}")
    if est.light_samples + est.bsdf_samples == 0:
        raise ValueError("MIS needs at least one light or BSDF sample")
    if not 0.0 < est.light_prob < 1.0:
        raise ValueError(f"light_prob must lie strictly between 0 and 1, got {est.light_prob}")
    for field, v in (("max_depth", est.max_depth), ("rr_depth", est.rr_depth)):
        if not isinstance(v, int | np.integer) or isinstance(v, bool):
            raise ValueError(f"{field} must be an integer, got {v!r}")
    v = est.ris_candidates
    if not isinstance(v, int | np.integer) or isinstance(v, bool) or v < 1:
        raise ValueError(f"ris_candidates must be an integer >= 1, got {v!r}")
    if est.nee not in NEE:
        raise ValueError(f"unknown next-event estimator {est.nee!r}; choose 'light' or 'ris'")
    if est.nee != "light" and est.name != "path":
        raise ValueError(f"nee applies to estimator='path' only, not {est.name!r}")
    resamples = est.name == "ris" or est.nee == "ris"
    if "ris_candidates" in params and not resamples \
            and v != Estimator._field_defaults["ris_candidates"]:
        raise ValueError("ris_candidates applies to estimator='ris' and to 'path' with "
                         f"nee='ris' only, not {est.name!r}")
    est = est._replace(ris_candidates=int(v))
    if est.name == "path":
        if not (est.max_depth == -1 or est.max_depth >= 1):
            raise ValueError(f"max_depth must be -1 (unbounded) or >= 1, got {est.max_depth}")
        if est.rr_depth < 1:
            raise ValueError(f"rr_depth must be >= 1, got {est.rr_depth}")
        if (est.light_samples, est.bsdf_samples) != (1, 1):
            raise ValueError("the path tracer takes one light and one BSDF sample per vertex; "
                             "light_samples and bsdf_samples apply to 'mis' only")
        return est._replace(max_depth=int(est.max_depth), rr_depth=int(est.rr_depth))
    for field in ("max_depth", "rr_depth"):
        if field in params and params[field] != Estimator._field_defaults[field]:
            raise ValueError(f"{field} applies to estimator='path' only, not {est.name!r}")
    return est
