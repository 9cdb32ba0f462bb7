"""What the applications (svr, mvr) share, below both: never imports svr or mvr.

* ``sdfcommon.tooling.commands``: the one shape of every hydra entry point (``hydra_entry``), its error
  handling (a user's mistake -> one line ``<prog>: error: <message>``, exit status 2), the clean-up
  of a failed run's folder, and validated config getters (``config_int``, ``config_float``, ...).
* ``sdfcommon.tooling.checks``: the one argument-checking module, one message format
  (``"<name> must be <expected>, got <value!r>"``): ``check_int``, ``check_float``, ``check_positive``,
  ``check_int_sequence``, ``check_instance``, ``check_shape``, ``check_tensor``, ``check_field_types``;
  for the Python APIs and the config getters alike.
* ``sdfcommon.tooling.serialization``: ``load_torch``, a tensors-and-values-only ``torch.load`` whose errors
  name the file and never advise ``weights_only=False``.
* ``sdfcommon.tooling.processes``: worker processes that die with their parent (``process_pool``).
* ``sdfcommon.tooling.pictures``: pictures people read (``labelled_grid``: tiles with labelled rows and
  columns).
"""
