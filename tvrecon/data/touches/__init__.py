"""Touches: the touch policies (where, in which direction and how hard the pad presses), the paper's sweep, which
cached touches a sample uses, which touches felt nothing, and pictures of a preset's touches."""
