"""USD side of composition (pxr from usd-core): catalog asset -> cached USD asset, SceneSpec -> stage."""
