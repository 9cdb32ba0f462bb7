"""What the two applications (svr, mvr) share, below both: this package never imports either, and
neither imports the other. ``sdfcommon.numerics`` holds the SDF grid regularisers, their fused
CPU kernel, marching cubes and ray casting against triangle meshes; ``sdfcommon.tooling`` holds the
command layer (``hydra_entry``, the one error handling that turns a user's mistake into one line ``<prog>: error: <message>`` with
exit status 2, the clean-up of a failed run's folder), typed settings built from configs
(``build_settings``), the one argument-checking module with its one message format
(``"<name> must be <expected>, got <value!r>"``, for the Python APIs and the settings alike), ``load_torch`` (a tensors-and-values-only ``torch.load`` whose errors name the file and
never advise ``weights_only=False``), atomic outputs, worker processes that die with their parent
(``process_pool``), labelled picture grids (``labelled_grid``) and host-memory tuning; each
module's docstring has the details.
"""
