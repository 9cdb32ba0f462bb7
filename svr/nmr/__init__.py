"""The NMR ShapeNet benchmark's own definitions, the lowest layer of ``svr``: its file format, splits,
categories and 24 views (``format``), its voxel frame and the voxelisation rules of its evaluation
(``voxels``), its IoU and the tables of it (``metrics``), SDF grids rendered from its views
(``views``) and the cones of rays through a silhouette (``cones``). Everything above reads the
dataset through these; none of them imports the rest of ``svr``."""
