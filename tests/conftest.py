"""Shared fixtures: an x64 switch so every kernel is also tested in double precision."""

import jax
import pytest


@pytest.fixture(params=[False, True], ids=["f32", "x64"])
def x64(request):
    """Run the test body once in float32 (default) and once under ``jax_enable_x64``."""
    with jax.enable_x64(request.param):
        yield request.param


@pytest.fixture
def enable_x64():
    """Run the test body under ``jax_enable_x64`` only."""
    with jax.enable_x64(True):
        yield
