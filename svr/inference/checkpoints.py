"""Checkpoints of single-view training read back (checkpoint -> network): the one module for
everything that loads a training checkpoint (training's stage hand-over and resume checks,
evaluation, inference, the demo), without importing Lightning. A checkpoint is a dict of tensors and
plain values (read weights-only), with our metadata under ``CHECKPOINT_KEY`` (the stage, the model
config that rebuilds the network, the grid's half side and resolution, the categories, training
seconds)."""
from __future__ import annotations

from typing import Any

import torch

from svr.models.checkpoint_layout import CHECKPOINT_KEY, STAGES
from svr.models.network import SVRNet

def load_checkpoint(path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Loads one of our Lightning checkpoints (tensors and plain values only) and checks it is ours.

    Raises:
        FileNotFoundError: no such file. ValueError: unreadable, truncated or not an SDFDiff
        single-view checkpoint (the message names the file).
    """
    from pathlib import Path

    from sdfcommon.tooling.serialization import load_torch

    p = Path(path)
    ckpt = load_torch(p, map_location)  # weights only; errors name the file, never advise unsafe loading
    if not isinstance(ckpt, dict) or CHECKPOINT_KEY not in ckpt or "state_dict" not in ckpt:
        raise ValueError(f"{p}: not an SDFDiff single-view checkpoint (no '{CHECKPOINT_KEY}' entry)")
    meta = ckpt[CHECKPOINT_KEY]
    if meta.get("stage") not in STAGES:
        raise ValueError(f"{p}: unknown training stage {meta.get('stage')!r} in the checkpoint")
    return ckpt


def load_network(path, map_location: str | torch.device = "cpu") -> tuple[SVRNet, dict[str, Any]]:
    """Rebuilds the network of a checkpoint from the model config stored in it, with its weights.

    Returns:
        (SVRNet in eval mode, the checkpoint's metadata: stage, half_side, grid_resolution,
        categories, model_config, skipped_steps).
    """
    from hydra.utils import instantiate

    ckpt = load_checkpoint(path, map_location)
    meta = ckpt[CHECKPOINT_KEY]
    if not meta.get("model_config"):
        raise ValueError(f"{path}: the checkpoint holds no model config to rebuild the network from")
    # A checkpoint is data: never let it name arbitrary callables for hydra to run.
    for target in _targets(meta["model_config"]):
        if not str(target).startswith("svr.models."):
            raise ValueError(f"{path}: its model config names {target!r}; only svr.models classes may be built")
    net = instantiate(meta["model_config"])
    if not isinstance(net, SVRNet):
        raise ValueError(f"{path}: its model config builds a {type(net).__name__}, not an SVRNet")
    load_network_weights(net, ckpt, path)
    net.to(map_location).eval()
    return net, dict(meta)


def _targets(config: Any):
    """Every ``_target_`` value in a nested dict/list config."""
    if isinstance(config, dict):
        for key, value in config.items():
            if key == "_target_":
                yield value
            else:
                yield from _targets(value)
    elif isinstance(config, (list, tuple)):
        for value in config:
            yield from _targets(value)


def load_network_weights(net: SVRNet, checkpoint: dict[str, Any], path) -> None:
    """Copies the network weights of a loaded checkpoint (``load_checkpoint``) into ``net``; strict:
    the architectures must match (the error names the file)."""
    state = {k[len("net."):]: v for k, v in checkpoint["state_dict"].items() if k.startswith("net.")}
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as err:
        raise ValueError(f"{path}: its network does not match the model ({err})") from None


__all__ = ["load_checkpoint", "load_network", "load_network_weights"]
