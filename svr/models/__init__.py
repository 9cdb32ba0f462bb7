"""The single-view networks (plain nn.Modules), in ``svr.models.module`` their LightningModule, and in
``svr.models.checkpoint_layout`` the stage names and the key of the checkpoints it writes."""
from svr.models.camera import ViewHead
from svr.models.decoder import SDFDecoder, sphere_template
from svr.models.encoder import ImageEncoder
from svr.models.local import PixelAlignedHead
from svr.models.network import SVRNet, SVRPrediction
from svr.models.prior import ShapePrior
from svr.models.refiner import BlockRefiner, SDFRefiner

__all__ = ["BlockRefiner", "ImageEncoder", "PixelAlignedHead", "SDFDecoder", "SDFRefiner", "SVRNet", "SVRPrediction", "ShapePrior", "ViewHead",
           "sphere_template"]
