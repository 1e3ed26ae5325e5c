"""Perception models: ResNet-18 branches, Agg fusion, Pixel2Mesh deformer, reconstructor and tactile classifier."""

from tvrecon.models.components.backbone import ResNet18Backbone, load_resnet18
from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.models.components.ellipsoid import (
    EllipsoidTemplate,
    mesh_edges,
    unpool_faces,
    unpool_features,
    uv_ellipsoid,
)
from tvrecon.models.components.fusion import (
    AggBlock,
    DirectionFFN,
    TactileVisualFusion,
    locate_touches,
    place_embeddings,
)
from tvrecon.models.components.gcn import DeformationBlock, GraphConv, GResBlock, MeshDeformer
from tvrecon.models.components.perceptual import PerceptualPooling
from tvrecon.models.components.projection import camera_to_pixel, project, project_with_depth
from tvrecon.models.components.reconstructor import TactileVisualReconstructor
from tvrecon.models.precision import best_precision, register_precision_resolver
from tvrecon.utils.geometry import world_to_camera

__all__ = [
    "AggBlock",
    "DeformationBlock",
    "DirectionFFN",
    "EllipsoidTemplate",
    "GResBlock",
    "GraphConv",
    "MeshDeformer",
    "PerceptualPooling",
    "ResNet18Backbone",
    "TactileClassifier",
    "TactileVisualFusion",
    "TactileVisualReconstructor",
    "best_precision",
    "camera_to_pixel",
    "load_resnet18",
    "locate_touches",
    "mesh_edges",
    "place_embeddings",
    "project",
    "project_with_depth",
    "unpool_faces",
    "unpool_features",
    "uv_ellipsoid",
    "world_to_camera",
]

register_precision_resolver()  # trainer.precision: ${best_precision:<accelerator>} in configs/trainer
