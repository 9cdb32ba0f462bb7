"""Evaluation by the benchmark's protocol: NMR voxels from SDF grids (``voxels``), IoU and tables of
it (``metrics``, ``tables``), the baselines scored beside a model (``baselines``) and the
protocol over a split (``benchmark``)."""
