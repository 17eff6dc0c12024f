"""Rays meet triangles: the watertight test, BVHs, eye-ray planes, convex bodies,
shadow-ray lists and ray origins."""
