"""Inference: checkpoints read back into networks (``checkpoints``, the only place a path becomes a
model, through ``prediction.load_model``), prediction of SDF grids from images (``prediction``), the
stored calibration applied to them (``calibration``), reconstructions written as grids, meshes and
previews (``reconstruction``), image files (``images``), the demo's pictures (``showcase``) and the
infer command's settings (``settings``)."""
