"""The single-view networks (plain nn.Modules) and, in ``svr.models.module``, their LightningModule."""
from .decoder import SDFDecoder, sphere_template
from .encoder import ImageEncoder
from .network import SVRNet, SVRPrediction
from .refiner import BlockRefiner, SDFRefiner

__all__ = ["BlockRefiner", "ImageEncoder", "SDFDecoder", "SDFRefiner", "SVRNet", "SVRPrediction", "sphere_template"]
