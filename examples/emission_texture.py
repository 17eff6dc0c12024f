"""A lamp whose radiance is an image: the Cornell box under a striped ceiling light.

    python examples/emission_texture.py                      # 128², 64 spp, ~1 min
    python examples/emission_texture.py --size 256 --spp 256 -o stripes

The box's ceiling light is enlarged (``--light-scale``, same power) and its radiance scaled
by an emission texture (:mod:`jaxrt.scene.textures`, ``textures={"emission": ...}``): three
stripes, red, green and blue, across the light, each of mean 1 so the lamp's power stays
the box's. Each block then casts three shadows of three colours: a point in the red
stripe's shadow still sees the green and the blue ones. Light samples, BSDF hits and camera
rays all read the texture at the point they reach; light selection uses each triangle's
mean. Writes ``<output>.exr`` (linear, with a ``stderr`` layer) and ``<output>.png``, and
returns (from :func:`main`) the render result and the scene.
"""

from __future__ import annotations

import argparse


def stripes(n: int = 3):
    """(1, 3n, 3): n red, n green, n blue columns (u across the light), each channel's
    stripe 3 so that every channel's mean over the lamp is 1."""
    import numpy as np

    texels = np.zeros((1, 3 * n, 3))
    for c in range(3):
        texels[0, c * n:(c + 1) * n, c] = 3.0
    return texels


def striped_box(size: int, light_scale: float):
    """The Cornell box of ``size``² pixels with a striped light ``light_scale`` times as large."""
    import jaxrt
    from jaxrt.scene.builtin.cornell import cornell_camera, cornell_meshes

    meshes = []
    for m in cornell_meshes(light_scale=light_scale):
        if m.name == "light":
            lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
            uv = (m.vertices[:, [0, 2]] - lo[[0, 2]]) / (hi[[0, 2]] - lo[[0, 2]])
            m = jaxrt.mesh(m.vertices, m.faces, m.material, emission=m.emission, name=m.name,
                           uv=uv, textures={"emission": jaxrt.texture(stripes(),
                                                                     filter="nearest")})
        meshes.append(m)
    return jaxrt.build_scene(meshes, cornell_camera(size, size))


def main(argv=None):
    import jaxrt
    from jaxrt.scene.images import write_exr, write_png

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--light-scale", type=float, default=2.5)
    ap.add_argument("--estimator", default="mis")
    ap.add_argument("-o", "--output", default="emission_texture")
    args = ap.parse_args(argv)
    scene = striped_box(args.size, args.light_scale)
    print(scene.summary())
    result = jaxrt.render(scene, args.estimator, spp=args.spp, seed=0)
    write_exr(f"{args.output}.exr", result.image, extra_channels={"stderr": result.stderr})
    write_png(f"{args.output}.png", result.image)
    print(f"wrote {args.output}.exr and {args.output}.png; image mean "
          f"{result.image.mean(axis=(0, 1)).round(4)}")
    return {"result": result, "scene": scene}


if __name__ == "__main__":
    main()
