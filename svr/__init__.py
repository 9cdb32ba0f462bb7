"""Single-view reconstruction (paper section 6): the commands ``train``, ``evaluate``, ``infer`` and
``demo`` at the top, and by role ``training`` (stage schedule, stopping, resume, run folders),
``evaluation`` (the benchmark's voxel protocol, metrics, baselines, tables), ``inference``
(checkpoints, prediction, pictures), ``models`` (the networks and their LightningModule) and
``data`` (the NMR format, data modules, the procedural generator)."""
