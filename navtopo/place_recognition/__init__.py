"""Global place descriptors for NavTopo: MinkLoc3D (learned, the paper's), a polar BEV CNN
(learned) and Scan Context (hand-made), behind one registry and one retrieval path.

    from navtopo.place_recognition import make_descriptor, retrieve
    descriptor = make_descriptor("minkloc3d")          # shipped weights
    embedding, signature = descriptor.describe_batch([points])
    matches = retrieve(descriptor, embedding[0], db_embeddings, k=5,
                       query_signature=signature[0], database_signatures=db_signatures)
"""

from . import minkloc3d, polar_bev, scan_context  # noqa: F401  (register the descriptors)
from .clouds import CropConfig, crop_cloud, rotate_yaw
from .learned import WEIGHTS_DIR, LearnedDescriptor, default_weights_path
from .minkloc3d import MinkLoc3D
from .polar_bev import PolarBEV
from .registry import (
    Cloud,
    PlaceDescriptor,
    available_descriptors,
    make_descriptor,
    register_descriptor,
)
from .retrieval import PlaceMatch, evaluate_recall, evaluate_revisits, nearest, retrieve
from .scan_context import ScanContext
from .training import (
    PlaceRecognitionDataset,
    TrainingConfig,
    TrainingProgress,
    batch_hard_triplet_loss,
    train,
)

__all__ = [
    "WEIGHTS_DIR",
    "Cloud",
    "CropConfig",
    "LearnedDescriptor",
    "MinkLoc3D",
    "PlaceDescriptor",
    "PlaceMatch",
    "PlaceRecognitionDataset",
    "PolarBEV",
    "ScanContext",
    "TrainingConfig",
    "TrainingProgress",
    "available_descriptors",
    "batch_hard_triplet_loss",
    "crop_cloud",
    "default_weights_path",
    "evaluate_recall",
    "evaluate_revisits",
    "make_descriptor",
    "nearest",
    "register_descriptor",
    "retrieve",
    "rotate_yaw",
    "train",
]
