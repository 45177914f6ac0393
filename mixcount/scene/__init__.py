"""Engine-free scene description and sampling (no bpy, no pxr): SceneSpec dataclasses and the sampler."""
