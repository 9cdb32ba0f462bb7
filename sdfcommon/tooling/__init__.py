"""The tooling both applications' commands share: the command layer (``commands``) and typed
settings (``settings``), argument checks (``checks``), atomic outputs (``outputs``), pictures,
worker processes, process memory tuning and safe checkpoint loading."""
