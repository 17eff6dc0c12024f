"""Inverse rendering of a texture: recover the Cornell box's back-wall albedo texture.

    python examples/inverse_texture.py               # 32², 8 × 8 texels, 250 steps, ~35 s
    python examples/inverse_texture.py --size 48 --steps 600 -o fit
    python examples/inverse_texture.py --size 48 --steps 400 --plot loss.png  # needs matplotlib

The box's back wall gets UVs (its corners at the unit square's) and an albedo texture of
``--texels``² texels (:mod:`jaxrt.scene.textures`, bilinear, clamped). A target image is
rendered with a true texture (a coloured checker of 2 × 2-texel squares over a gradient);
the fit starts from a uniform grey texture (0.5) and descends the L2 loss
``mean_p |I_p(θ) − T_p|²`` with Adam (optax) on the texels' logits (albedo = sigmoid(θ):
always in (0, 1)). Each step's gradient is :func:`jaxrt.gradient` w.r.t.
``"textures.0"``: the image at one seed, ``∂loss/∂I`` at it, and the vector–Jacobian
product of an independent image, so the stochastic gradient is unbiased.

Texels the camera hardly sees (behind the tall block, or at the image's border: less than a
tenth of a typical texel's share of the image's gradient) are reported, not fitted. The loss
printed is that of each step's noisy image (its MC noise is most of it); the texel error is
the one to watch. Prints the loss curve (every 25 steps) and the
texels' error; writes ``<output>_before.png`` and ``<output>_after.png`` (the start and the
fitted image beside the target), with ``--plot PATH`` a figure of the loss and of the seen
texels' median error per step (needs matplotlib), and returns (from :func:`main`) a dict
with the history, the textures and the errors.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

TEX = "textures.0"


def true_texture(n: int) -> np.ndarray:
    """(n, n, 3): a checker of 2 × 2-texel squares, warm and cool, over a left-right ramp."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    checker = ((i // 2 + j // 2) % 2)[..., None]
    ramp = (0.5 + 0.5 * j / max(n - 1, 1))[..., None]
    return np.where(checker == 0, [0.85, 0.55, 0.2], [0.15, 0.35, 0.75]) * ramp


def textured_box(size: int, texels: np.ndarray):
    """The Cornell box of ``size``² pixels with ``texels`` as its back wall's albedo."""
    import jaxrt
    from jaxrt.scene.builtin.cornell import cornell_camera, cornell_meshes

    meshes = []
    for m in cornell_meshes():
        if m.name == "back":
            # u along x (from the wall's left, seen from the camera), v up along y
            lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
            uv = (m.vertices[:, :2] - lo[:2]) / (hi[:2] - lo[:2])
            uv[:, 0] = 1 - uv[:, 0]  # the camera looks along +z: +x is to its left
            m = jaxrt.mesh(m.vertices, m.faces, m.material, name=m.name, uv=uv,
                           textures={"kd": jaxrt.texture(texels, wrap="clamp")})
        meshes.append(m)
    return jaxrt.build_scene(meshes, cornell_camera(size, size))


def _fit(args) -> dict:
    import jax
    import jax.numpy as jnp
    import optax

    import jaxrt

    truth = true_texture(args.texels)
    start = np.full_like(truth, 0.5)
    box = textured_box(args.size, truth)
    target = jaxrt.estimate_image(box, "mis", spp=args.target_spp, seed=10_000)
    # which texels the image sees: the gradient of the image's sum (a texel that reaches
    # less than a tenth of a typical one's pixels is hardly constrained: reported, not fitted)
    sens = jaxrt.image_vjp(box, jnp.ones_like(target), "mis", spp=4, seed=1, params=(TEX,))[TEX]
    reach = np.asarray(jnp.abs(sens).sum(axis=2))
    seen = reach > 0.1 * np.median(reach[reach > 0])

    logit = jnp.log(jnp.asarray(start, jnp.float32) / (1 - jnp.asarray(start, jnp.float32)))
    opt = optax.adam(optax.exponential_decay(args.lr, args.steps, 0.05))
    state = opt.init(logit)

    def loss(image):
        return jnp.mean((image - target) ** 2)

    history, texel_error, mask = [], [], jnp.asarray(seen[..., None], jnp.float32)
    err = lambda t: np.abs(np.asarray(t, np.float64) - truth)[seen] / truth[seen]  # noqa: E731
    t0 = time.perf_counter()
    for step in range(args.steps):
        texels = jax.nn.sigmoid(logit)
        g = jaxrt.gradient(loss, jaxrt.with_params(box, {TEX: texels}), "mis", spp=args.spp,
                           primal_spp=args.primal_spp, seed=step, params=(TEX,))
        # chain rule through the sigmoid; unseen texels are not moved
        updates, state = opt.update(g.grads[TEX] * texels * (1 - texels) * mask, state)
        logit = optax.apply_updates(logit, updates)
        history.append(float(g.loss))
        texel_error.append(float(np.median(err(jax.nn.sigmoid(logit)))))
        if args.verbose and (step % 25 == 0 or step == args.steps - 1):
            print(f"step {step:4d}  loss {history[-1]:.3e}  texel error (median) "
                  f"{np.median(err(jax.nn.sigmoid(logit))):6.1%}  "
                  f"{time.perf_counter() - t0:6.1f} s", flush=True)
    fitted = np.asarray(jax.nn.sigmoid(logit), np.float64)
    images = {name: np.asarray(jaxrt.estimate_image(jaxrt.with_params(
        box, {TEX: jnp.asarray(t, jnp.float32)}), "mis", spp=args.target_spp, seed=20_000))
        for name, t in (("start", start), ("fitted", fitted))}
    images["target"] = np.asarray(target)
    return dict(loss=np.asarray(history), texel_error=np.asarray(texel_error), truth=truth,
                start=start, fitted=fitted, seen=seen, rel_error=err(fitted),
                initial_rel_error=err(start), images=images, seconds=time.perf_counter() - t0)


def _save(res: dict, output: str) -> list[str]:
    from jaxrt.scene.images import write_png

    paths = []
    for name in ("start", "fitted"):
        path = f"{output}_{'before' if name == 'start' else 'after'}.png"
        write_png(path, np.concatenate([res["images"][name], res["images"]["target"]], axis=1))
        paths.append(path)
    return paths


def plot(res: dict, path: str) -> str:
    """Write a figure of the loss and of the seen texels' median error per step to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.arange(1, len(res["loss"]) + 1)
    fig, (a, b) = plt.subplots(1, 2, figsize=(8, 3), constrained_layout=True)
    a.semilogy(steps, res["loss"], lw=0.6, color="0.6", label="each step")
    k = min(20, len(steps))
    if k > 1:
        smooth = np.convolve(res["loss"], np.ones(k) / k, mode="valid")
        a.semilogy(steps[k - 1:], smooth, color="C0", label=f"mean of {k}")
    a.set(xlabel="Adam step", ylabel="loss (noisy image vs target)", title="loss")
    a.legend(frameon=False)
    b.semilogy(np.concatenate([[0], steps]),
               100 * np.concatenate([[np.median(res["initial_rel_error"])], res["texel_error"]]),
               color="C1")
    b.set(xlabel="Adam step", ylabel="relative error (%)",
          title=f"median texel error ({int(res['seen'].sum())} seen texels)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=int, default=32, help="image width and height")
    p.add_argument("--texels", type=int, default=8, help="texture width and height")
    p.add_argument("--steps", type=int, default=250, help="Adam steps")
    p.add_argument("--spp", type=int, default=8, help="samples per pixel of each gradient")
    p.add_argument("--primal-spp", type=int, default=16,
                   help="samples per pixel of the image whose residual weights each gradient")
    p.add_argument("--target-spp", type=int, default=1024, help="samples of the target image")
    p.add_argument("--lr", type=float, default=0.1, help="Adam step size (logits)")
    p.add_argument("-o", "--output", default="inverse_texture",
                   help="prefix of the two PNGs (start | target, fitted | target)")
    p.add_argument("--plot", metavar="PATH",
                   help="also write a figure of the loss and texel error per step (matplotlib)")
    p.add_argument("-q", "--quiet", dest="verbose", action="store_false")
    args = p.parse_args(argv)
    try:
        import optax  # noqa: F401
    except ImportError as e:
        raise SystemExit("this example needs optax: pip install 'jaxrt[optim]'") from e
    res = _fit(args)
    print(f"{args.steps} steps in {res['seconds']:.1f} s; loss {res['loss'][0]:.3e} → "
          f"{res['loss'][-20:].mean():.3e} (mean of the last 20)")
    print(f"  {int(res['seen'].sum())} of {res['seen'].size} texels seen; relative error "
          f"(seen texels, per channel) median {np.median(res['initial_rel_error']):.1%} → "
          f"{np.median(res['rel_error']):.1%}, max {res['rel_error'].max():.1%}")
    for path in _save(res, args.output):
        print(f"wrote {path}")
    if args.plot:
        print(f"wrote {plot(res, args.plot)}")
    return res


if __name__ == "__main__":
    main()
