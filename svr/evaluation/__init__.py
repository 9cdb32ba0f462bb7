"""Evaluation by the benchmark's protocol: NMR voxels from SDF grids (``voxels``), IoU and tables of
it (``metrics``, ``tables``), the baselines scored beside a model (``baselines``) and the
protocol over a split (``benchmark``), and the scores of a finished run as the demo reports them
(``run_scores``)."""
