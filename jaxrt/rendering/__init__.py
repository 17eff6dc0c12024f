"""From estimators to images: the render driver, its passes, the program cache and
differentiable images."""
