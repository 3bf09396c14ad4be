"""Capture: scenes, their files (COLMAP, LLFF, nerfstudio, Middlebury), poses from photos, sparse points."""
