"""Numerical code on SDF grids that both applications use: the eikonal and Laplacian regularisers
(``regularisers``, the PyTorch specification, and ``band_kernel``, the same narrow-band terms as one
fused numba CPU operation) and marching cubes from grids to meshes (``meshing``).
"""
