"""What a scene holds (meshes, materials, lights, camera), its ray queries, its files
and the built-in scenes."""
