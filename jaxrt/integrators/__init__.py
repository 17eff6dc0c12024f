"""The estimators: terms of the reflection equation, direct illumination, the
path tracer, and the registry of techniques."""
