"""Single-view reconstruction (paper section 6), in layers, lowest first (each imports only those
before it; tests/test_layering.py checks it): ``nmr`` (the benchmark's NMR format, voxel frame, IoU
and views) and ``distributed`` (process groups); ``data`` (datasets, samplers, DataModules, the
procedural generator, the mesh builder); ``losses``; ``models`` (the networks, their
LightningModule, the checkpoint's stage names and key); ``inference`` (checkpoints, prediction,
calibration, pictures); ``training`` (stage schedule, stopping, resume, run folders) and
``evaluation`` (the benchmark protocol run, baselines, tables, the calibration search);
``scoring`` (a finished run scored as the demo reports it); the commands ``train``, ``evaluate``,
``infer`` and ``demo``."""
