"""Tests users run on their own samplers and estimators: chi-square, its domains,
analytic oracles and the warp gallery."""
