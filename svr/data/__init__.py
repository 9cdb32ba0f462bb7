"""Single-view data: the NMR ShapeNet format (``nmr``), the procedural dataset in that format
(``procedural``: its shape categories in ``categories``, built on the analytic CSG shapes of
``csg``), the Lightning DataModules (``datamodule``) and the batch contract (``types``). The names
below are loaded on first use (``__getattr__``) for start-up cost: every import of a submodule
(``svr.data.nmr`` by the evaluation tables, ``svr.data.types`` by the models) runs this file first,
and importing the DataModules here would load Lightning and the procedural generator into every
command and worker process that needs only the NMR format.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "SVRBatch": "types", "ShadingModel": "types", "collate_batch": "types",
    "NMRDataset": "nmr", "NMR_CATEGORIES": "nmr", "prepare_nmr": "nmr",
    "ALL_CATEGORIES": "procedural.categories", "NMR_PROCEDURAL_CATEGORIES": "procedural.categories",
    "ProceduralSettings": "procedural.generator",
    "generate_procedural_dataset": "procedural.generator", "ensure_procedural_dataset": "procedural.generator",
    "make_shape": "procedural.generator", "render_shape": "procedural.generator",
    "voxelize_shape": "procedural.generator",
    "NMRDataModule": "datamodule", "ProceduralDataModule": "datamodule",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
