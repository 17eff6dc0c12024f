"""Built-in scenes: the Cornell box and its variants, a Veach-style MIS scene, many lamps.

Every function returns a :class:`jaxrt.scene.container.Scene`; ``width``/``height`` set the image
size, ``accel`` and the light options are passed to :func:`jaxrt.scene.container.build_scene`.

========================  ====================================================================
name                      what it shows
========================  ====================================================================
``cornell_box``           the classic box (Cornell's measured dimensions, in metres): one
                          ceiling area light, red and green walls, two white boxes
``cornell_box_small``     the same box lit by a light 1/10 the size, 100× brighter (same power):
                          hemisphere and BSDF sampling are hopeless, light sampling shines
``cornell_box_glossy``    a Phong floor, a rough-conductor tall box and a mirror short box:
                          every BSDF kind in one scene
``veach_mis``             four plates from rough to nearly smooth, lit by four sphere lights from
                          large to tiny of equal power: where light sampling and BSDF sampling
                          each win, and MIS gets both (Veach 1997, fig. 9.2)
``lamp_grid``             a room under 24 × 24 small ceiling lamps (1 152 emissive triangles),
                          radiances over two orders of magnitude: many-light sampling (RIS)
========================  ====================================================================
"""

from jaxrt.scene.builtin.cornell import cornell_box, cornell_box_glossy, cornell_box_small
from jaxrt.scene.builtin.lamp_grid import lamp_grid
from jaxrt.scene.builtin.veach import veach_mis

BUILTIN = {
    "cornell_box": cornell_box,
    "cornell_box_small": cornell_box_small,
    "cornell_box_glossy": cornell_box_glossy,
    "veach_mis": veach_mis,
    "lamp_grid": lamp_grid,
}


def by_name(name: str, **kwargs):
    """Build a built-in scene by name (see :data:`BUILTIN`); clear error for unknown names."""
    try:
        fn = BUILTIN[name]
    except KeyError:
        raise ValueError(f"unknown built-in scene {name!r}; choose one of "
                         f"{', '.join(sorted(BUILTIN))}") from None
    return fn(**kwargs)


__all__ = ["BUILTIN", "by_name", "cornell_box", "cornell_box_glossy", "cornell_box_small",
           "lamp_grid", "veach_mis"]
