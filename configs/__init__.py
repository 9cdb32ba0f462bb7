"""The hydra configs of every command, shipped with the package as the module ``sdfdiff_configs``
(pyproject.toml maps it to this folder), so console scripts find them outside the checkout."""
