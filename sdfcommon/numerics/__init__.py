"""Numerical code that both applications use: on SDF grids, the eikonal and Laplacian regularisers
(``regularisers``, the PyTorch specification, and ``band_kernel``, the same narrow-band terms as one
fused numba CPU operation) and marching cubes from grids to meshes (``meshing``); on triangle
meshes, ray casting (``raycast``: Embree, with a numba grid as the fallback backend); from
silhouettes, the fields of their cones and visual hull (``hull``); re-distancing a grid with its
surface kept (``redistance``).
"""
