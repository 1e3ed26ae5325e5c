"""Losses (chamfer, Pixel2Mesh mesh terms) and evaluation metrics."""

from tvrecon.losses.chamfer import ChamferDistance, ChamferResult, chamfer_distance, chamfer_terms, nearest_neighbors
from tvrecon.losses.mesh import (
    DEFAULT_WEIGHTS,
    MeshLoss,
    edge_length_loss,
    laplacian_coordinates,
    laplacian_loss,
    mesh_loss_terms,
    move_loss,
    normal_loss,
)
from tvrecon.losses.metrics import (
    DEFAULT_FSCORE_THRESHOLDS,
    chamfer_metric,
    chamfer_metric_points,
    fscore,
    fscore_points,
    sample_points_on_mesh,
)

__all__ = [
    "DEFAULT_FSCORE_THRESHOLDS",
    "DEFAULT_WEIGHTS",
    "ChamferDistance",
    "ChamferResult",
    "MeshLoss",
    "chamfer_distance",
    "chamfer_metric",
    "chamfer_metric_points",
    "chamfer_terms",
    "edge_length_loss",
    "fscore",
    "fscore_points",
    "laplacian_coordinates",
    "laplacian_loss",
    "mesh_loss_terms",
    "move_loss",
    "nearest_neighbors",
    "normal_loss",
    "sample_points_on_mesh",
]
