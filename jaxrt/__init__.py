"""jaxrt: batched Monte Carlo estimators for physically based rendering in JAX.

The package mirrors the rendering pipeline (samples → warps → rays → intersections →
shading → estimators → render → files); see README.md for a tour.
"""

import sys
import types

__version__ = "0.1.0"

# The top-level names load lazily so that ``import jaxrt.cli`` stays light (no JAX) and no
# import cycle can form between the pipeline's modules and this package.
_LAZY = {
    "Scene": ("jaxrt.scene", "Scene"),
    "build_scene": ("jaxrt.scene", "build_scene"),
    "mesh": ("jaxrt.scene", "mesh"),
    "render": ("jaxrt.render", "render"),
    "RenderResult": ("jaxrt.render", "RenderResult"),
    "RenderInterrupted": ("jaxrt.render", "RenderInterrupted"),
    "load_scene": ("jaxrt.scene_file", "load_scene"),
    "chi2_test": ("jaxrt.testing", "chi2_test"),
    "estimate_image": ("jaxrt.differentiable", "estimate_image"),
    "image_vjp": ("jaxrt.differentiable", "image_vjp"),
    "gradient": ("jaxrt.differentiable", "gradient"),
    "scene_params": ("jaxrt.differentiable", "scene_params"),
    "with_params": ("jaxrt.differentiable", "with_params"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'jaxrt' has no attribute {name!r}")


__all__ = list(_LAZY)



class _Package(types.ModuleType):
    """This package's module type. ``render`` is both a submodule and a function: when the
    submodule loads, the import system sets the package attribute ``jaxrt.render`` to the
    module, which made ``jaxrt.render`` a function once (through ``__getattr__``) and a
    module from then on. The function is kept instead (``sys.modules["jaxrt.render"]`` and
    ``from jaxrt.render import ...`` still give the module)."""

    def __setattr__(self, name, value):
        if name == "render" and isinstance(value, types.ModuleType):
            value = value.render
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
