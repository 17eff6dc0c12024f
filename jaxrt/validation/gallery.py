"""A one-page picture of every warp: point set, sample histogram, integrated pdf.

For each warp of :data:`jaxrt.sampling.warp.REGISTRY` (its first chi-square-friendly parameter), one
row of three panels: the warped points (2D domains as they are, directions projected to the
(x, y) plane), the histogram of ``num_samples`` samples in the chi-square harness's cell
coordinates, and the expected counts ``N ∫_cell pdf`` that the harness integrated from the
warp's own pdf. The row title carries the χ² p-value. matplotlib (Agg) is imported lazily.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxrt.sampling import warp as W
from jaxrt.scene.images import write_atomically
from jaxrt.validation.chi2 import chi2_test
from jaxrt.validation.domains import SQUARE, Domain, resolve_domain

# parameter index shown per warp (peaked lobes need finer grids than a gallery row)
GALLERY_INDEX = {"phong_lobe": 2, "ggx": 1, "beckmann": 1}


def registry_domain(spec: W.WarpSpec) -> Domain:
    """The harness :class:`Domain` of a registry entry, building ``("square", lo, hi)``."""
    d = spec.domain
    if isinstance(d, tuple) and d[0] == "square":
        lo, hi = float(d[1]), float(d[2])
        w, tol = hi - lo, 1e-5 * (hi - lo)
        return SQUARE._replace(
            name=f"square[{lo:g}, {hi:g}]",
            to_cell_coords=lambda x: (x - lo) / w,
            from_cell_coords=lambda s: lo + w * s,
            jacobian=w * w,
            in_domain=lambda x: jnp.all(jnp.isfinite(x) & (x >= lo - tol) & (x <= hi + tol)),
        )
    return resolve_domain(d)


def _sampler(spec, args):
    if spec.dim == 1:
        return lambda u: spec.sample(u[0], *args)
    return lambda u: spec.sample(u, *args)


def make_gallery(path, num_samples: int = 100_000, resolution=(32, 16), seed: int = 0,
                 num_points: int = 2_000, progress: bool = False):
    """Draw every registry warp into one PNG at ``path``; returns the list of χ² results.

    Args: ``path`` output file; ``num_samples`` per histogram; ``resolution`` of the
    (s1, s2) grid; ``seed``; ``num_points`` drawn in the scatter panels; ``progress``: a bar
    on stderr naming the warp being compiled and tested (each is a compile of its own).
    """
    try:
        import matplotlib
    except ImportError:
        raise ImportError("the warp gallery draws with matplotlib, which is not installed: "
                          "pip install 'jaxrt[plot]'") from None

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    specs = W.REGISTRY
    fig, axes = plt.subplots(len(specs), 3, figsize=(10, 2.6 * len(specs)), squeeze=False)
    results = []
    bar = _bar(len(specs), progress)
    for row, spec in zip(axes, specs, strict=True):
        bar.set_postfix_str(spec.name)
        params = spec.params[GALLERY_INDEX.get(spec.name, 0)]
        args = tuple(jnp.asarray(p, jnp.float32) for p in params)
        samp = _sampler(spec, args)
        dom = registry_domain(spec)
        res = chi2_test(samp, lambda x, args=args, spec=spec: spec.pdf(x, *args), dom,
                        num_samples=num_samples, resolution=resolution, seed=seed)
        results.append(res)
        u = jax.random.uniform(jax.random.PRNGKey(seed), (num_points, 2), jnp.float32)
        x = np.asarray(jax.vmap(samp)(u))
        ax = row[0]
        if spec.dim == 1:
            ax.scatter(x, u[:, 1], s=1)
            ax.set_xlabel("x")
        else:
            # directions: (x, y) projection coloured by z; 2-D points as they are
            if spec.dim == 3:
                ax.scatter(x[:, 0], x[:, 1], s=1, c=x[:, 2], cmap="viridis")
            else:
                ax.scatter(x[:, 0], x[:, 1], s=1)
            ax.set_aspect("equal")
        label = ", ".join(f"{np.round(np.asarray(p), 3).tolist()}" for p in params)
        ax.set_title(f"{spec.name}({label})"[:48], fontsize=8)
        vmax = max(res.observed.max(), res.expected.max())
        for ax, table, name in ((row[1], res.observed, "observed"),
                                (row[2], res.expected, "expected (∫ pdf)")):
            if table.shape[1] == 1:
                ax.bar(np.arange(table.shape[0]), table[:, 0], width=1.0)
                ax.set_ylim(0, vmax * 1.05)
            else:
                ax.imshow(table.T, origin="lower", aspect="auto", vmin=0, vmax=vmax,
                          extent=(0, 1, 0, 1))
                ax.set_xlabel(res.axis_names[0], fontsize=7)
                ax.set_ylabel(res.axis_names[1], fontsize=7)
            verdict = "pass" if res.passed else "FAIL"
            ax.set_title(f"{name}  χ² p={res.p_value:.2g} {verdict}", fontsize=8)
        bar.update(1)
    bar.close()
    fig.tight_layout()
    # to a temporary file renamed over ``path``: an interrupted run leaves no half a picture
    write_atomically(path, lambda f: fig.savefig(f, format="png", dpi=70))
    plt.close(fig)
    return results


class _NoBar:
    def set_postfix_str(self, s):
        pass

    def update(self, n):
        pass

    def close(self):
        pass


def _bar(total: int, show: bool):
    if not show:
        return _NoBar()
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _NoBar()
    import sys

    return tqdm(total=total, unit="warp", desc="gallery", file=sys.stderr)
