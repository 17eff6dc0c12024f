"""Light source models: sample a direction towards a shading point, evaluate, and give its pdf.

Kinds, one module each: :mod:`.delta` (point, spot, directional), :mod:`.area` (emissive
triangles, sampled by area or by solid angle), :mod:`.sphere` (spheres, sampled by the cone they
subtend), :mod:`.environment` (constant or lat-long map). :mod:`.table` gathers them into the
``Lights`` pytree (static counts per kind, so absent kinds compile no code), selects a light
uniformly, by power or by a light BVH (:mod:`jaxrt.scene.lights.bvh`, a pmf that depends on the
shading point), and dispatches.

Build on the host, then use inside ``jit``/``vmap``::

    lights = light_table([point_light([0, 0, 2], [10, 10, 10]),
                          triangle_lights(tris, radiance, prims),
                          constant_environment([0.1, 0.1, 0.1])],
                         triangle_sampling="area", selection="power")
    s = jax.vmap(sample_li, (None, 0, 0, 0))(lights, p, n, u)     # u: (B, 3)
    pdf = pdf_li(lights, p, wi, light, p_light)                     # for MIS

Global light indices follow the kind order point, spot, directional, triangle, sphere,
environment (see :mod:`.table`).
"""

from jaxrt.scene.lights.area import TriangleLights, triangle_lights
from jaxrt.scene.lights.delta import (
    DirectionalLights,
    PointLights,
    SpotLights,
    directional_light,
    point_light,
    spot_light,
)
from jaxrt.scene.lights.environment import (
    ConstantEnvironment,
    EnvironmentMap,
    constant_environment,
    environment_map,
)
from jaxrt.scene.lights.records import LightSample, luminance
from jaxrt.scene.lights.sphere import SphereLights, sphere_light
from jaxrt.scene.lights.table import (
    KINDS,
    Lights,
    LightsStructure,
    environment_light_index,
    intersect_spheres,
    le_environment,
    le_sphere,
    le_triangle,
    light_powers,
    light_table,
    pdf_li,
    sample_li,
    select_light,
    selection_pmf,
    triangle_light_index,
)

__all__ = [
    "KINDS",
    "ConstantEnvironment",
    "DirectionalLights",
    "EnvironmentMap",
    "LightSample",
    "Lights",
    "LightsStructure",
    "PointLights",
    "SphereLights",
    "SpotLights",
    "TriangleLights",
    "constant_environment",
    "directional_light",
    "environment_light_index",
    "environment_map",
    "intersect_spheres",
    "le_environment",
    "le_sphere",
    "le_triangle",
    "light_powers",
    "light_table",
    "luminance",
    "pdf_li",
    "point_light",
    "sample_li",
    "select_light",
    "selection_pmf",
    "sphere_light",
    "spot_light",
    "triangle_light_index",
    "triangle_lights",
]
