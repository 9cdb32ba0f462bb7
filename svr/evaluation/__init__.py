"""Evaluation by the benchmark's protocol (its voxel and IoU rules are ``svr.nmr``'s): the protocol
run over a split (``protocol``), the baselines scored beside a model (``baselines``), the tables of
the result (``tables``), the calibration searched on the validation split and stored in a
checkpoint (``calibration_search``; ``svr.inference.calibration`` applies it) and the evaluate
command's settings (``settings``)."""
