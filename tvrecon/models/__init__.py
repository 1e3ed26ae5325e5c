"""Perception models: ResNet-18 branches, Agg fusion, Pixel2Mesh deformer, reconstructor and tactile classifier."""

from tvrecon.models.backbone import ResNet18Backbone, load_resnet18
from tvrecon.models.classifier import TactileClassifier
from tvrecon.models.ellipsoid import EllipsoidTemplate, mesh_edges, unpool_faces, unpool_features, uv_ellipsoid
from tvrecon.models.fusion import AggBlock, DirectionFFN, TactileVisualFusion, locate_touches, place_embeddings
from tvrecon.models.gcn import DeformationBlock, GraphConv, GResBlock, MeshDeformer, PerceptualPooling
from tvrecon.models.projection import camera_to_pixel, project, project_with_depth, world_to_camera
from tvrecon.models.reconstructor import TactileVisualReconstructor

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
