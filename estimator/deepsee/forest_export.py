"""The random forest as a served model: one ONNX file that the service, ``seesys estimator estimate`` and the
evaluation load like an exported DeepSEE (:class:`estimator.artefact.onnx_model.OnnxModel`).

The graph takes what every served model takes, ``rts`` (B, T, C) float32 (normalised) and ``psd`` (B, K_L, H, W, 3)
uint8, and returns ``y`` (B,), the transformed error. The forest reads the RTS window only: the graph computes its
window statistics (:func:`estimator.deepsee.forest.window_statistics`: mean, population standard deviation,
minimum, maximum and last value of each channel, in that order) with ONNX operators, and the trees are scikit-learn's,
converted by skl2onnx into ONNX-ML's ``TreeEnsembleRegressor``. The ``psd`` input is declared at the installation's
PSD grid and left unread, so the service checks a device's windows against it as for any model. The forest's
compatibility record (its pickle's) and its training cameras go into the metadata as :mod:`estimator.deepsee.export`
writes them for DeepSEE.

A forest of 100 trees on the reduced schedule's 15,000 windows is about 12 MB and runs a window in microseconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper
from sklearn.ensemble import RandomForestRegressor

from estimator.artefact.onnx_model import FOREST_KIND, OnnxModel, Y, export_metadata
from estimator.deepsee.forest import window_statistics
from seesys.core.psd import PsdGeometry

#: ONNX's default and ML operator sets of the exported graph (ONNX Runtime 1.31 runs both).
OPSET = 17
ML_OPSET = 3
#: Largest difference of the exported forest from scikit-learn's on the transformed scale: the trees compare the same
#: float32 features; only the order of the float32 sums over trees and window rows differs.
FOREST_PARITY_TOLERANCE = 1e-4
_FEATURES = "features"


def _statistics_nodes(rts_length: int) -> list[onnx.NodeProto]:
    """``rts`` (B, T, C) → ``features`` (B, 5·C): mean, std, min, max, last value per channel."""
    last = helper.make_tensor("last", TensorProto.INT64, [], [rts_length - 1])
    return [
        helper.make_node("Constant", [], ["last"], value=last),
        helper.make_node("ReduceMean", ["rts"], ["mean"], axes=[1], keepdims=0),
        helper.make_node("ReduceMean", ["rts"], ["mean_kept"], axes=[1], keepdims=1),
        helper.make_node("Sub", ["rts", "mean_kept"], ["centred"]),
        helper.make_node("Mul", ["centred", "centred"], ["squared"]),
        helper.make_node("ReduceMean", ["squared"], ["variance"], axes=[1], keepdims=0),
        helper.make_node("Sqrt", ["variance"], ["std"]),
        helper.make_node("ReduceMin", ["rts"], ["min"], axes=[1], keepdims=0),
        helper.make_node("ReduceMax", ["rts"], ["max"], axes=[1], keepdims=0),
        helper.make_node("Gather", ["rts", "last"], ["end"], axis=1),
        helper.make_node("Concat", ["mean", "std", "min", "max", "end"], [_FEATURES], axis=1),
    ]


def _trees(forest: RandomForestRegressor) -> onnx.GraphProto:
    """The forest as skl2onnx converts it: ``features`` (B, F) → its one output (B, 1)."""
    from skl2onnx import convert_sklearn
    from skl2onnx.common.data_types import FloatTensorType

    proto = convert_sklearn(
        forest,
        initial_types=[(_FEATURES, FloatTensorType([None, forest.n_features_in_]))],
        target_opset={"": OPSET, "ai.onnx.ml": ML_OPSET},
    )
    return proto.graph


def psd_shape_of(record: dict, psd_samples: int) -> tuple[int, int, int]:
    """(K_L, H, W) of the PSD windows for the device settings of a compatibility ``record``: the reference camera's
    grid (camera normalisation puts every camera's PSD on it)."""
    device = record["device"]
    camera = device["reference_camera"]
    height, width, _ = PsdGeometry(
        camera["width"], camera["height"], device["psd_patch_px"], device["psd_expansion"]
    ).shape
    return psd_samples, height, width


def export_forest_onnx(
    record: dict, path: Path, rts_length: int, psd_shape: tuple[int, int, int], cameras: list[str] | None = None
) -> Path:
    """Write the random forest of ``record`` (its pickle's: ``forest``, ``compatibility``) as one ONNX file for
    windows of ``rts_length`` rows and PSD matrices of ``psd_shape`` (K_L, H, W), with its ``cameras``."""
    forest: RandomForestRegressor = record["forest"]
    channels = len(record["compatibility"]["rts_channels"])
    if forest.n_features_in_ != 5 * channels:
        raise ValueError(
            f"the forest takes {forest.n_features_in_} features, not the 5 statistics of its {channels} channels"
        )
    trees = _trees(forest)
    # The converter's output (B, 1) flattened to the served model's y (B,).
    nodes = [
        *_statistics_nodes(rts_length),
        *trees.node,
        helper.make_node("Constant", [], ["flat"], value=helper.make_tensor("flat", TensorProto.INT64, [1], [-1])),
        helper.make_node("Reshape", [trees.output[0].name, "flat"], [Y]),
    ]
    layers, height, width = psd_shape
    graph = helper.make_graph(
        nodes,
        "seesys_random_forest",
        [
            helper.make_tensor_value_info("rts", TensorProto.FLOAT, ["batch", rts_length, channels]),
            helper.make_tensor_value_info("psd", TensorProto.UINT8, ["batch", layers, height, width, 3]),
        ],
        [helper.make_tensor_value_info(Y, TensorProto.FLOAT, ["batch"])],
        initializer=list(trees.initializer),
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET), helper.make_opsetid("ai.onnx.ml", ML_OPSET)]
    )
    model.ir_version = 8
    onnx.checker.check_model(model)
    for key, value in export_metadata(record["compatibility"], FOREST_KIND, cameras):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path))
    return path


def forest_parity(forest: RandomForestRegressor, model: OnnxModel, windows: int = 500, seed: int = 0) -> float:
    """Largest absolute difference between scikit-learn's forest on :func:`window_statistics` and the exported
    graph on the same random normalised windows (transformed scale)."""
    rng = np.random.default_rng(seed)
    shape = model.shape
    rts = rng.normal(size=(windows, shape.rts_length, shape.channels)).astype(np.float32)
    psd = np.zeros((windows, shape.psd_samples, shape.psd_height, shape.psd_width, 3), np.uint8)
    expected = forest.predict(window_statistics(rts))
    return float(np.abs(model(rts, psd) - expected).max())
