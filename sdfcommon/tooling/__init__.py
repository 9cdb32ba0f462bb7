"""The tooling both applications' commands share: the command layer (``commands``; the command
line composed before hydra runs it and the ``--help`` with the YAML comments, ``command_line`` and
``config_comments``) and typed settings (``settings``), argument checks (``checks``; against this
machine's hardware, ``hardware``), atomic outputs (``outputs``), pictures, worker processes,
process memory tuning and safe checkpoint loading."""
