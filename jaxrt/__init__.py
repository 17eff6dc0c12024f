"""jaxrt: batched Monte Carlo estimators for physically based rendering in JAX.

The package mirrors the rendering pipeline (samples → warps → rays → intersections →
shading → estimators → render → files); see README.md and docs/ for a tour.
"""

__version__ = "0.1.0"

# The top-level names load lazily so that ``jaxrt.cli`` stays light (no JAX) and no import
# cycle can form between the pipeline's modules and this package.
_LAZY = {
    "Scene": ("jaxrt.scene.container", "Scene"),
    "build_scene": ("jaxrt.scene.container", "build_scene"),
    "mesh": ("jaxrt.scene.container", "mesh"),
    "render": ("jaxrt.rendering.driver", "render"),
    "RenderResult": ("jaxrt.rendering.driver", "RenderResult"),
    "RenderInterrupted": ("jaxrt.rendering.driver", "RenderInterrupted"),
    "load_scene": ("jaxrt.scene.file", "load_scene"),
    "look_at": ("jaxrt.scene.camera", "look_at"),
    "texture": ("jaxrt.scene.textures", "texture"),
    "load_texture": ("jaxrt.scene.textures", "load_texture"),
    "estimate_at": ("jaxrt.integrators.point", "estimate_at"),
    "chi2_test": ("jaxrt.validation.chi2", "chi2_test"),
    "estimate_image": ("jaxrt.rendering.differentiable", "estimate_image"),
    "image_vjp": ("jaxrt.rendering.differentiable", "image_vjp"),
    "gradient": ("jaxrt.rendering.differentiable", "gradient"),
    "scene_params": ("jaxrt.rendering.differentiable", "scene_params"),
    "with_params": ("jaxrt.rendering.differentiable", "with_params"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'jaxrt' has no attribute {name!r}")


__all__ = list(_LAZY)
