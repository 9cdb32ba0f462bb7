"""Single-view data in the NMR ShapeNet format (``svr.nmr``): the torch Datasets over a folder
(``datasets``), which items the loaders read on each process (``samplers``), the Lightning
DataModules (``datamodules``), the batch contract (``types``), the procedural dataset in that format
(``procedural``: its shape categories in ``categories``, built on the analytic CSG shapes of
``csg``) and the mesh-to-NMR builder (``build``). The names below are loaded on first use
(``__getattr__``) for start-up cost: every import of a submodule (``svr.data.types`` by the models)
runs this file first, and importing the DataModules here would load Lightning and the procedural
generator into every command and worker process that needs only the batch types.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "SVRBatch": "types", "ShadingModel": "types", "collate_batch": "types",
    "NMRDataset": "datasets",
    "ALL_CATEGORIES": "procedural.categories", "NMR_PROCEDURAL_CATEGORIES": "procedural.categories",
    "ProceduralSettings": "procedural.generator",
    "generate_procedural_dataset": "procedural.generator", "ensure_procedural_dataset": "procedural.generator",
    "make_shape": "procedural.generator", "render_shape": "procedural.generator",
    "voxelize_shape": "procedural.generator",
    "SVRDataModule": "datamodules", "NMRDataModule": "datamodules", "ProceduralDataModule": "datamodules",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
