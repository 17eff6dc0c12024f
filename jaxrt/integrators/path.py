"""Global illumination: a unidirectional path tracer with next-event estimation and MIS.

The rendering equation replaces the emitted radiance of the reflection equation by all the
radiance arriving at x,

    L(x, wo) = L_e(x, wo) + ∫_{H²} f(x, wi, wo) L(r(x, wi), −wi) |cos θi| dwi,

and its Neumann series sums paths x₀ (camera) → x₁ → … → x_D of D segments. The estimator
walks one path per camera sample. At every surface vertex x_k it

1. samples a light (``jaxrt.integrators.terms.light_term``: one light sample, light chosen by the
   scene's selection pmf) and adds ``β · w_l · f L_e |cos θi| / p_l`` when the shadow ray is
   free (next-event estimation, NEE);
2. samples the BSDF (``jaxrt.integrators.terms.bsdf_direction``), multiplies the throughput ``β`` by
   ``f |cos θi| / p_b`` and traces the ray (``trace_from``): the emitter it finds adds
   ``β · w_b · L_e``; the surface it hits is the next vertex.

``w_l``, ``w_b`` are the MIS weights of the two techniques (``heuristic``: balance or power,
one sample each), exactly as in the ``mis`` estimator: the direct light at each vertex is the
``mis`` estimate, with the throughput of the path before it. Delta lights are reached only
by NEE (weight 1); a delta BSDF lobe (mirror) gives NEE nothing (f = 0 off the mirror
direction) and its BSDF sample weight 1; point, spot and directional lights are never hit.
Environment light is found by rays that escape (and sampled by NEE). Sphere lights emit
and end the path (they do not reflect).

Depth convention (Mitsuba 3's ``path`` integrator, so ``max_depth`` compares one for one):
``max_depth`` is the largest number of path segments, the camera ray included.
``max_depth = 1``: emitters seen by the camera only; ``2``: plus direct illumination (the
``mis`` estimator with one light and one BSDF sample); ``D``: light reflected up to D − 1
times; ``−1``: unbounded. Inside a closed furnace of albedo ρ whose walls emit L_e, a path of
at most D segments sees ``L_e (1 − ρ^D) / (1 − ρ)``.

Russian roulette (pbrt-v4's rule): after the BSDF sample of the k-th vertex (k = 1 at the
first surface the camera sees), if ``k ≥ rr_depth`` and the throughput's largest component
``m = max_c β_c`` is below 1, the path survives with probability ``q = m`` and ``β`` is
divided by q: unbiased, since E[1{u < q}/q] = 1, and after it ``max β = 1``, so β never
grows and every path's value stays bounded (by L_e times its length). Mitsuba 3 caps q at
0.95 instead: then β grows by ρ/0.95 per bounce while paths survive with 0.95, and for a
throughput factor ρ > √0.95 ≈ 0.975 per bounce the estimator's variance is infinite (a
ρ = 0.999 furnace came out at 14–38 % of its value, 6 of 8 seeds beyond 5σ:
tests/integrators/test_path.py). The price: a path keeps going as long as its throughput does (about
1/(1 − ρ) bounces in a furnace of albedo ρ). q carries no derivative (it is a sampling
decision). "Unbounded" paths stop at :data:`MAX_SEGMENTS` segments, so that a lossless
closed scene (a perfect mirror box) cannot run forever; only such a scene loses light by it
(a path of throughput factor ρ reaches 2^16 segments with probability ρ^65536).

Random dimensions: vertex k (from 1) uses ``b = 2 + 6 (k − 1)``: the pair (b, b+1) for the
point on the light, b+2 to choose the light, b+3 for the roulette, the pair (b+4, b+5) for
the BSDF. The first vertex's light and BSDF dimensions are those of ``mis`` (2–4 and 6–7),
so ``max_depth=2`` renders the ``mis`` image from the same random numbers.

Next-event estimation by RIS (``nee="ris"``, :func:`jaxrt.integrators.ris.resampled_light`):
``ris_candidates`` = M light samples resampled by their unshadowed contribution, one shadow
ray, the chosen sample weighted by MIS against the BSDF sample from the two sampling
densities (light sampling's ``p_l``, not RIS's own density of the chosen point, which has no
closed form): the BSDF sample's hits of emitters keep ``w_b`` from the same two densities,
so the weights still sum to one. Vertex k then uses ``6 + 3 (M − 1) + 1`` dimensions: the
six above (candidate 0 on the light's three), then three per further candidate and one for
the choice.

Batching without waste: a step of the walk is one segment — scatter at the current vertex
(NEE, BSDF sample, roulette), trace the continuing ray, add the emission it finds. Vmapped
over the lanes of a pass, a ``lax.while_loop`` of steps runs in lockstep, so one path per
lane would make the whole batch wait for its longest path (on the 256² Cornell box, 16 384
lanes, unbounded: 22 % of lane-steps useful). In a render pass each lane instead carries
its pixel's ``count`` samples one after the other (:func:`pass_sums`): when a lane's path
ends, the same step folds its value into the pixel's sums and starts the lane's next camera
ray (path regeneration), so a lane is idle only once its last sample is done; and when at
most a quarter of the lanes still run, those are gathered into a batch a quarter the size
(the BVH's compaction: once, or up to three times for passes of one or two samples per lane
in long renders, :func:`compactions`; every stage is a copy of the step in the compiled
program).
Samples are folded in index order, so the sums are those of the plain loop over samples,
bit for bit. Useful lane-steps, 256² Cornell box, unbounded, 32 samples per pass, per batch
of 16 384 lanes: 22 % in lockstep (one path per lane), 55–71 % with regeneration, 71–83 %
with regeneration and one compaction (75–87 % with three, for 3× the compile time;
benchmarks/README.md#path-lanes).
:func:`path` (one path from a given vertex: ``estimate_at``, ``camera_sample``) runs the
same step without regeneration.

Derivatives: as for the direct estimators (sampling detached: every sampled direction, pdf,
MIS weight and roulette probability is held fixed, ``β`` carries the derivative of
``f |cos θi| / p`` at the fixed direction): forward mode (``jax.jvp``,
:func:`jaxrt.rendering.differentiable.derivative_at`) works at any depth. Reverse mode
(:func:`jaxrt.rendering.differentiable.image_vjp`, :func:`jaxrt.rendering.differentiable.gradient`)
works for paths of bounded depth, whose per-sample walk is a ``fori_loop``; JAX does not
reverse-differentiate a ``while_loop``, so unbounded paths, and ``jax.grad`` of
``estimate_image`` (whose pass regenerates paths in a ``while_loop``), are refused or fail.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array, lax

from jaxrt.core.vecmath import computed_once
from jaxrt.integrators.ris import resampled_light
from jaxrt.integrators.terms import (
    ShadingPoint,
    Stream,
    bsdf_direction,
    camera_ray,
    light_term,
    mis_weight,
    receiver_normal,
    shading_point,
    trace_from,
)
from jaxrt.scene.container import Scene
from jaxrt.scene.queries import TRIANGLE

if TYPE_CHECKING:  # annotations only: jaxrt.integrators.direct imports this module
    from jaxrt.integrators.config import Estimator

#: Random dimensions per path vertex (see the module notes).
DIMS_PER_VERTEX = 6
#: Where "unbounded" paths stop (module notes: only lossless closed scenes get this far).
MAX_SEGMENTS = 1 << 16


def vertex_dims(est: Estimator) -> int:
    """Random dimensions per path vertex: :data:`DIMS_PER_VERTEX`, plus 3 per further RIS
    candidate and 1 for the choice among them when ``est.nee == "ris"`` (module notes)."""
    if est.nee == "ris":
        return DIMS_PER_VERTEX + 3 * (est.ris_candidates - 1) + 1
    return DIMS_PER_VERTEX


def path_dims(max_depth: int, per_vertex: int = DIMS_PER_VERTEX) -> int | None:
    """Random dimensions of one camera sample of a path of at most ``max_depth`` segments
    (None when unbounded): 2 for the pixel, ``per_vertex`` (:func:`vertex_dims`) per
    scattering vertex."""
    if max_depth < 0:
        return None
    return 2 + per_vertex * max(max_depth - 1, 0)


class PathState(NamedTuple):
    """One path at a vertex: where it is, what it carries, what it has gathered."""

    x: ShadingPoint  # the current vertex (meaningful while ``active``)
    beta: Array  # (3,) throughput: Π f |cos θi| / p over the segments so far (/ q for RR)
    radiance: Array  # (3,) light gathered so far
    vertex: Array  # () int32: k, the index of the current vertex (1 = first surface)
    active: Array  # () bool: the path scatters at x


class Segment(NamedTuple):
    """The ray leaving a vertex, with what weighs the emission it will find."""

    o: Array  # (3,) origin
    d: Array  # (3,) unit direction
    p: Array  # (3,) the vertex it leaves (light-sampling pdf of d is taken there)
    pdf_bsdf: Array  # () density of d under BSDF sampling
    unweighted: Array  # () bool: its emission takes weight 1 (delta lobe, camera ray)
    n: Array | None = None  # (3,) the vertex's normal, where light selection depends on it


def _can_scatter(est: Estimator, hit, vertex: Array) -> Array:
    depth = MAX_SEGMENTS if est.max_depth < 0 else est.max_depth
    return (hit.kind == TRIANGLE) & (vertex < depth)


def _ris_nee(scene: Scene, est: Estimator, st: PathState, s: Stream, base: Array) -> Array:
    """Next-event estimation by RIS (``est.nee == "ris"``), MIS-weighted against the BSDF
    sample: candidate 0 on light sampling's dimensions ``base … base + 2``, candidate
    ``k ≥ 1`` on ``base + 6 + 3 (k − 1) …``, the choice on the dimension after them."""
    more = lambda k: base + DIMS_PER_VERTEX + 3 * (k - 1)
    dims = lambda k: (jnp.where(k == 0, base, more(k)), jnp.where(k == 0, base + 2, more(k) + 2))
    return resampled_light(scene, st.x, s, est.ris_candidates, dims, more(est.ris_candidates),
                           heuristic=est.heuristic)


def scatter(scene: Scene, est: Estimator, st: PathState, s: Stream) -> tuple[PathState, Segment]:
    """At ``st.x``: next-event estimation, then the BSDF sample that continues the path and
    Russian roulette. Returns the state with NEE added, β updated (``active`` False when the
    path ends here) and the segment to trace. Lanes with ``st.active`` False are unchanged."""
    base = 2 + vertex_dims(est) * (st.vertex - 1)
    if est.nee == "ris":
        radiance = st.radiance + jnp.where(st.active, st.beta * _ris_nee(scene, est, st, s, base),
                                           0)
    else:
        tl = light_term(scene, st.x, s.u2(base), s.u1(base + 2))
        wl = jnp.where(tl.is_delta, 1, mis_weight(est.heuristic, 1, tl.pdf_light, 1,
                                                  tl.pdf_bsdf))
        # stored once, as in `arrive`: fused into the (3,) radiance below, the weight (both
        # pdfs, the light's table rows gathered) would be computed per component
        # (benchmarks/README.md#computed-once)
        wl = computed_once(wl)
        radiance = st.radiance + jnp.where(st.active, st.beta * wl * tl.value, 0)
    # read by the state and, when the path ends here, by the fold into the pixel's four sums
    radiance = computed_once(radiance)
    b = bsdf_direction(scene, st.x, s.u2(base + 4))
    beta = st.beta * b.weight
    active = st.active
    if est.max_depth < 0 or est.max_depth > est.rr_depth:
        beta, active = _roulette(beta, active, st.vertex >= est.rr_depth, s.u1(base + 3))
    active = active & (jnp.max(beta) > 0)
    beta = jnp.where(st.active, beta, st.beta)
    seg = Segment(b.o, b.wi, st.x.hit.p, b.pdf, b.is_delta, receiver_normal(scene, st.x.n))
    return st._replace(beta=beta, radiance=radiance, active=active), seg


def arrive(scene: Scene, est: Estimator, st: PathState, seg: Segment) -> PathState:
    """Trace ``seg`` (for paths still active), add the emission found with its MIS weight
    against light sampling at ``seg.p``, and move to the vertex hit."""
    a = trace_from(scene, seg.p, seg.o, seg.d, n=seg.n)
    w = jnp.where(seg.unweighted, 1, mis_weight(est.heuristic, 1, seg.pdf_bsdf, 1, a.pdf_light))
    # stored once: fused into the (3,) sum below, the weight (the light's pdf at the hit, its
    # table rows gathered) would be computed per component (stored: path pass 1.03× as fast)
    w = computed_once(w)
    radiance = st.radiance + jnp.where(st.active, st.beta * w * a.le, 0)
    vertex = st.vertex + 1
    return PathState(shading_point(scene, a.hit, -seg.d), st.beta, radiance, vertex,
                     st.active & _can_scatter(est, a.hit, vertex))


def path(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Radiance reflected at the first vertex ``x`` towards the camera (3,): the sum over
    path lengths 2 … max_depth of NEE and BSDF-sampled emission, MIS-weighted (module notes).

    The emission of ``x`` itself is not included (``camera_sample`` adds the emitter the
    camera sees); 0 when ``max_depth == 1``.
    """
    return trace_path(scene, est, x, s).radiance


def trace_path(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> PathState:
    """The walk of :func:`path`, returning its final state (``vertex``: the index of the
    vertex where the path ended, i.e. the steps it took; for measurements).

    Unbounded paths run a ``while_loop`` until the path ends; paths of at most ``max_depth``
    segments run a ``fori_loop`` of ``max_depth − 1`` steps (ended paths step on unchanged:
    every term is masked by ``active``), which JAX can reverse-differentiate: this is what
    :func:`jaxrt.rendering.differentiable.image_vjp` runs for ``path``."""
    dtype = x.hit.p.dtype
    start = PathState(x, jnp.ones(3, dtype), jnp.zeros(3, dtype), jnp.int32(1),
                      _can_scatter(est, x.hit, jnp.int32(1)))
    step = lambda st: arrive(scene, est, *scatter(scene, est, st, s))  # noqa: E731
    if est.max_depth > 0:
        return lax.fori_loop(0, est.max_depth - 1, lambda _, st: step(st), start)
    return lax.while_loop(lambda st: st.active, step, start)


#: Lanes of a pass are compacted when the running ones fit in a quarter of them, at most
#: :func:`compactions` times (never more than this), never below MIN_COMPACT_LANES (as the
#: BVH's traversal: below it the fixed cost of a step's kernels dominates). Every stage is a
#: copy of the step in the program.
MAX_COMPACTIONS = 3
MIN_COMPACT_LANES = 256


def compactions(count: int, samples: int) -> int:
    """How many times a pass of ``count`` samples per lane compacts its lanes, for a render
    of ``samples`` samples in all (pixels × spp; static).

    Each compaction is a copy of the step in the program (+3.5–4 s of compile on a 2-core
    Zen 4), and it pays where few samples per lane leave lanes idle: with one sample per lane
    there is no regeneration, and every batch waits for its longest path. A 256² Cornell box
    pass, unbounded, per 65 536 samples (ms of CPU; the sums bit-identical across
    compactions):

    =================== ====== ====== ======
    compactions / count 1      2      4
    =================== ====== ====== ======
    1                   122    88     70
    2                   93     72     62
    3                   82
    =================== ====== ====== ======

    (8 samples per lane: 71.) So a second compaction pays for its compile after ~13 M
    samples at count 1 and ~32 M at count 2, a third after ~52 M at count 1. With a margin
    of 2: 2 compactions from 2.5·10⁷ samples at count 1 and 6.4·10⁷ at count 2, 3 from 10⁸
    at count 1, otherwise 1. Passes of 2 samples are render's default from ~0.7 megapixels,
    of 1 above 2^20 pixels (:func:`jaxrt.rendering.driver.default_spp_per_pass`): a 1920×1080 render
    of 16 spp or more gets 2, of 64 or more 3 (benchmarks/README.md#path-lanes). An unbounded
    render (``spp=None``: a time budget or a target error) counts as one pass, its length
    unknown when the pass compiles: it keeps 1 unless its passes are long enough alone.
    """
    if count == 1:
        return 3 if samples >= 100_000_000 else 2 if samples >= 25_000_000 else 1
    return 2 if count == 2 and samples >= 64_000_000 else 1


class _Lane(NamedTuple):
    pixel: Array  # () int32 flat pixel
    k: Array  # () int32 the pass's sample in flight (−1 before the first, count: done)
    st: PathState
    acc: Any  # the pixel's sums


def pass_sums(scene: Scene, est: Estimator, stream: Callable[[Array, Array], Stream],
              pixels: Array, count: int, acc, fold: Callable, compact: int = 1):
    """``acc`` advanced by the samples ``0 … count−1`` of each pixel of ``pixels`` (N,),
    each lane one path after another with regeneration (module notes); ``stream(pixel, k)``
    is sample k's stream, ``acc`` has a leading axis of N.

    ``fold(acc, value)`` adds one sample's radiance (3,) to a pixel's sums; a pixel's samples
    are folded in order. Each sample's value is the one
    :func:`jaxrt.integrators.techniques.camera_sample` computes. The lanes step in lockstep until at
    most a quarter still run; those are gathered into a batch a quarter the size, ``compact``
    times at most (:func:`compactions`), down to :data:`MIN_COMPACT_LANES` (the BVH's
    schedule: only the schedule changes, not any lane's steps: the sums are the same bit for
    bit).
    """
    if not 0 <= compact <= MAX_COMPACTIONS:
        raise ValueError(f"compact must be in 0 … {MAX_COMPACTIONS}, not {compact}")
    dtype = acc.s1.dtype

    def start(pixel, acc):
        s0 = stream(pixel, jnp.int32(0))
        o, d = camera_ray(scene, pixel, s0)
        # no path in flight before the first step: a vertex of zeros (only its shape matters)
        shape = jax.eval_shape(lambda: shading_point(scene, trace_from(scene, o, o, d).hit, -d))
        nowhere = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shape)
        idle = PathState(nowhere, jnp.ones(3, dtype), jnp.zeros(3, dtype), jnp.int32(0),
                         jnp.bool_(False))
        return _Lane(pixel, jnp.int32(-1), idle, acc)

    def step(lane: _Lane) -> _Lane:
        pixel, k, st, acc = lane
        st, seg = scatter(scene, est, st, stream(pixel, k))
        # a lane whose path has ended folds its sample and starts the next camera ray
        ended = ~st.active
        # (lanes past their last sample, or padding, step on without folding anything)
        acc = _where(ended & (k >= 0) & (k < count), fold(acc, st.radiance), acc)
        k = jnp.where(ended, k + 1, k)
        # stored scalars: the direction feeds the select below (camera.generate_ray)
        o, d = camera_ray(scene, pixel, stream(pixel, k), stored=True)
        # (a camera ray's emission is unweighted: its normal, zero, is never read)
        camera = Segment(o, d, o, jnp.zeros((), dtype), jnp.bool_(True),
                         receiver_normal(scene, jnp.zeros(3, dtype)))
        seg = _where(ended, camera, seg)
        st = _where(ended, PathState(st.x, jnp.ones(3, dtype), jnp.zeros(3, dtype),
                                     jnp.int32(0), k < count), st)
        return _Lane(pixel, k, arrive(scene, est, st, seg), acc)

    # a sample's path ends inside the loop; the step after folds it (k reaches count)
    running = lambda lanes: lanes.k < count
    steps = jax.vmap(step)
    lanes = jax.vmap(start)(pixels, acc)
    n = pixels.shape[0]
    ids = jnp.arange(n, dtype=jnp.int32)
    out, width = acc, n
    for _ in range(compact):  # static: the widths are known at trace time
        if width // 4 < MIN_COMPACT_LANES:
            break
        cap = width // 4
        lanes = lax.while_loop(lambda c, cap=cap: jnp.sum(running(c)) > cap, steps, lanes)
        # every lane's sums so far (final for the finished ones) ...
        out = jax.tree.map(lambda o, a, ids=ids: o.at[ids].set(a, mode="drop"), out, lanes.acc)
        # ... then the running lanes, in order, into a batch of `cap` (the rest: padding)
        live = running(lanes)
        (sel,) = jnp.nonzero(live, size=cap, fill_value=0)
        pad = jnp.arange(cap) >= jnp.sum(live)
        lanes = jax.tree.map(lambda a, sel=sel: a[sel], lanes)
        lanes = lanes._replace(k=jnp.where(pad, count, lanes.k))
        ids = jnp.where(pad, n, ids[sel])
        width = cap
    lanes = lax.while_loop(lambda c: jnp.any(running(c)), steps, lanes)
    return jax.tree.map(lambda o, a: o.at[ids].set(a, mode="drop"), out, lanes.acc)


def _where(c: Array, a, b):
    """``a`` where ``c`` else ``b``, leaf by leaf (a per-lane ``c`` over pytrees)."""
    return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


def _roulette(beta: Array, active: Array, applies: Array, u: Array) -> tuple[Array, Array]:
    """Russian roulette (pbrt-v4): below full throughput, survive with ``q = max β`` and
    divide β by q (so that ``max β = 1`` after it)."""
    q = lax.stop_gradient(jnp.max(beta))
    applies = applies & (q < 1)
    beta = jnp.where(applies, beta / jnp.where(q > 0, q, 1), beta)
    return beta, active & (~applies | (u < q))
