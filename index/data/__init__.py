"""Datasets read from disk: BOP-format scenes, cameras, ground truth and meshes (`bop`)."""
