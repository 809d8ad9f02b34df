"""One router per resource: environments, meshes, scenes, frames (and one-shot renders), health."""
