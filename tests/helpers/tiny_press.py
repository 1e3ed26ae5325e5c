"""The coarse press the data tests generate with: an 8 x 8 x 3 pad on a 32^3 grid, a shallow touch, so that an item
generates in a second or two (overrides of any preset, e.g. ``cls_tiny``)."""

TINY_PRESS = [
    "sensor.resolution=[8,8]",
    "sensor.layers=3",
    "press.n_grid=32",
    "press.max_depth=1.5",
    "press.gap=0.5",
    "press.speed_fraction=0.2",
    "touch.depth_fractions=[0.1]",
]
