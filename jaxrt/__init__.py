"""jaxrt: batched Monte Carlo estimators for physically based rendering in JAX.

The package mirrors the rendering pipeline (samples → warps → rays → intersections →
shading → estimators → render → files); see README.md for a tour.
"""

__version__ = "0.1.0"

# The top-level names load lazily so that no import cycle can form between the pipeline's
# modules and this package -- except ``render``, below.
_LAZY = {
    "Scene": ("jaxrt.scene", "Scene"),
    "build_scene": ("jaxrt.scene", "build_scene"),
    "mesh": ("jaxrt.scene", "mesh"),
    "render": ("jaxrt.render", "render"),
    "RenderResult": ("jaxrt.render", "RenderResult"),
    "load_scene": ("jaxrt.scene_file", "load_scene"),
    "chi2_test": ("jaxrt.testing", "chi2_test"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'jaxrt' has no attribute {name!r}")


__all__ = list(_LAZY)

# ``render`` is both a submodule and a function. Importing the submodule (which any
# ``import jaxrt.render`` or ``from jaxrt.render import ...`` does, once) sets the package
# attribute ``jaxrt.render`` to the module; binding the function here, after that import, makes
# ``jaxrt.render`` the function for good (``sys.modules["jaxrt.render"]`` stays the module).
from jaxrt.render import render  # noqa: E402, F401

