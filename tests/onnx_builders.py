"""Small ONNX models (built with onnx.helper, opset 17) that follow the I/O
contracts of spgeo's ONNX front-end, for tests.

* :func:`sam_encoder`: (1,3,1024,1024) -> ``image_embeddings`` (1,256,64,64):
  16x16 average pooling of the (normalised, padded) input, channels tiled,
  so the embedding carries the image.
* :func:`sam_decoder`: the official segment-anything decoder contract; the C
  candidate logits are discs around the first point,
  ``k_i * (r_i - distance)`` in ORIGINAL-image pixels (the graph undoes the
  longest-side-1024 scaling using ``orig_im_size``).  ``iou_predictions`` are
  ``ious + iou_slope_u * u_prompt``.  ``offset`` moves the discs away from
  the prompt.  The default radii (4, 10.5, 20.5) / slopes (0.2, 30, 30) make
  candidate 0 unstable (stability 0) and the others stable (>= 0.99 on the
  pixel lattice; integer radii put lattice points on the boundary).
* :func:`efficientsam_encoder` / :func:`efficientsam_decoder`: the
  EfficientSAM split contract (batched queries, original-pixel coordinates).
* :func:`normal_model`: decodes an RGB image as colour-coded normals
  ``2 * rgb - 1`` (after undoing the configured mean/std), optionally with a
  4th (confidence) channel or a separate confidence output.
* :func:`depth_model`: a plane's inverse depth (or depth), affine in the
  normalised pixel coordinates at any input size, plus a term that is zero
  only when the front-end normalised a grey-0.5 image as configured.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def _const(name: str, value) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(value), name)


def _save(graph: onnx.GraphProto, path) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="spgeo-tests")
    model.ir_version = 8
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path


# ------------------------------------------------------------------ SAM
def sam_encoder(path, input_name: str = "x", output_name: str = "image_embeddings",
                size: int = 1024) -> Path:
    """AveragePool 16 of the (1,3,size,size) input, tiled to 256 channels."""
    g = size // 16
    nodes = [
        helper.make_node("AveragePool", [input_name], ["pooled"], kernel_shape=[16, 16],
                         strides=[16, 16]),
        helper.make_node("Tile", ["pooled", "reps"], ["tiled"]),
        helper.make_node("Slice", ["tiled", "s0", "s1", "sax"], [output_name]),
    ]
    graph = helper.make_graph(
        nodes, "sam_encoder",
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, [1, 256, g, g])],
        [_const("reps", np.array([1, 86, 1, 1], np.int64)), _const("s0", np.array([0], np.int64)),
         _const("s1", np.array([256], np.int64)), _const("sax", np.array([1], np.int64))])
    return _save(graph, path)


def sam_encoder_hwc_raw(path, input_name: str = "input_image", size: int = 1024) -> Path:
    """(h, w, 3) resized 0-255 image -> normalise, CHW, pad to size x size -> as sam_encoder."""
    g = size // 16
    inits = [_const("mean", np.array([123.675, 116.28, 103.53], np.float32)),
             _const("std", np.array([58.395, 57.12, 57.375], np.float32)),
             _const("full", np.array([size, size], np.int64)),
             _const("hw_s", np.array([0], np.int64)), _const("hw_e", np.array([2], np.int64)),
             _const("zeros4", np.zeros(4, np.int64)), _const("zero1", np.zeros(1, np.int64)),
             _const("ax0", np.array([0], np.int64)),
             _const("reps", np.array([1, 86, 1, 1], np.int64)),
             _const("s0", np.array([0], np.int64)), _const("s1", np.array([256], np.int64)),
             _const("sax", np.array([1], np.int64))]
    nodes = [
        helper.make_node("Sub", [input_name, "mean"], ["a"]),
        helper.make_node("Div", ["a", "std"], ["b"]),
        helper.make_node("Transpose", ["b"], ["chw"], perm=[2, 0, 1]),
        helper.make_node("Unsqueeze", ["chw", "ax0"], ["nchw"]),
        helper.make_node("Shape", [input_name], ["shp"]),
        helper.make_node("Slice", ["shp", "hw_s", "hw_e"], ["hw"]),
        helper.make_node("Sub", ["full", "hw"], ["padhw"]),
        # pads: [n0, c0, h0, w0, n1, c1, h1, w1] = [0, 0, 0, 0, 0, 0, size-h, size-w]
        helper.make_node("Concat", ["zeros4", "zero1", "zero1", "padhw"], ["pads"], axis=0),
        helper.make_node("Pad", ["nchw", "pads"], ["padded"], mode="constant"),
        helper.make_node("AveragePool", ["padded"], ["pooled"], kernel_shape=[16, 16],
                         strides=[16, 16]),
        helper.make_node("Tile", ["pooled", "reps"], ["tiled"]),
        helper.make_node("Slice", ["tiled", "s0", "s1", "sax"], ["image_embeddings"]),
    ]
    graph = helper.make_graph(
        nodes, "sam_encoder_hwc",
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, ["h", "w", 3])],
        [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, g, g])],
        inits)
    return _save(graph, path)


def _disc_nodes(px: str, py: str, rows: str, cols: str, radii, slopes, prefix: str):
    """Nodes computing (C, H, W) logits k*(r - dist) for a scalar centre (px, py)."""
    c = len(radii)
    inits = [_const(prefix + "K", np.asarray(slopes, np.float32).reshape(c, 1, 1)),
             _const(prefix + "R", np.asarray(radii, np.float32).reshape(c, 1, 1)),
             _const(prefix + "ax0", np.array([0], np.int64)),
             _const(prefix + "ax1", np.array([1], np.int64))]
    p = prefix
    nodes = [
        helper.make_node("Sub", [rows, py], [p + "dy"]),
        helper.make_node("Sub", [cols, px], [p + "dx"]),
        helper.make_node("Mul", [p + "dy", p + "dy"], [p + "dy2"]),
        helper.make_node("Mul", [p + "dx", p + "dx"], [p + "dx2"]),
        helper.make_node("Unsqueeze", [p + "dy2", p + "ax1"], [p + "dy2c"]),   # (H,1)
        helper.make_node("Unsqueeze", [p + "dx2", p + "ax0"], [p + "dx2r"]),   # (1,W)
        helper.make_node("Add", [p + "dy2c", p + "dx2r"], [p + "d2"]),
        helper.make_node("Sqrt", [p + "d2"], [p + "d"]),
        helper.make_node("Unsqueeze", [p + "d", p + "ax0"], [p + "d3"]),       # (1,H,W)
        helper.make_node("Sub", [p + "R", p + "d3"], [p + "rd"]),
        helper.make_node("Mul", [p + "K", p + "rd"], [p + "logits"]),          # (C,H,W)
    ]
    return nodes, inits, p + "logits"


def _touch_inputs(names: Sequence[str], out: str) -> list:
    """Nodes computing ``out = 0 * sum of every input`` (needs the "zero" constant), so that
    every named input is part of the graph."""
    nodes = [helper.make_node("ReduceSum", [n], [f"touch_{i}"], keepdims=0)
             for i, n in enumerate(names)]
    acc = "touch_0"
    for i in range(1, len(names)):
        nodes.append(helper.make_node("Add", [acc, f"touch_{i}"], [f"touch_sum{i}"]))
        acc = f"touch_sum{i}"
    nodes.append(helper.make_node("Mul", [acc, "zero"], [out]))
    return nodes


def sam_decoder(path, radii: Sequence[float] = (4.0, 10.5, 20.5),
                slopes: Sequence[float] = (0.2, 30.0, 30.0),
                ious: Sequence[float] = (0.99, 0.9, 0.8), iou_slope_u: float = 1e-4,
                offset: Sequence[float] = (0.0, 0.0),
                input_names: Optional[Sequence[str]] = None) -> Path:
    """Official SAM decoder contract with disc-shaped candidates (see module doc)."""
    names = list(input_names or ["image_embeddings", "point_coords", "point_labels",
                                 "mask_input", "has_mask_input", "orig_im_size"])
    emb, pc, pl, mi, hm, osz = names
    c = len(radii)
    inits = [
        _const("c1024", np.array(1024.0, np.float32)), _const("half", np.array(0.5, np.float32)),
        _const("zero", np.array(0.0, np.float32)), _const("one", np.array(1.0, np.float32)),
        _const("idx_wh", np.array([1, 0], np.int64)), _const("i0", np.array(0, np.int64)),
        _const("i1", np.array(1, np.int64)), _const("p_s", np.array([0], np.int64)),
        _const("p_e", np.array([1], np.int64)), _const("p_ax", np.array([1], np.int64)),
        _const("shape2", np.array([2], np.int64)),
        _const("offset", np.asarray(offset, np.float32)),
        _const("iou_base", np.asarray(ious, np.float32).reshape(1, c)),
        _const("iou_slope", np.array(iou_slope_u, np.float32)),
        _const("ax0", np.array([0], np.int64)),
        _const("lowres", np.zeros((1, c, 256, 256), np.float32)),
    ]
    nodes = [
        # orig size -> longest-side-1024 size; ratio original / resized per axis
        helper.make_node("ReduceMax", [osz], ["maxs"], keepdims=0),
        helper.make_node("Div", ["c1024", "maxs"], ["scale"]),
        helper.make_node("Mul", [osz, "scale"], ["ts0"]),
        helper.make_node("Add", ["ts0", "half"], ["ts1"]),
        helper.make_node("Floor", ["ts1"], ["tsize"]),
        helper.make_node("Div", [osz, "tsize"], ["ratio_hw"]),
        helper.make_node("Gather", ["ratio_hw", "idx_wh"], ["ratio_xy"], axis=0),
        # first point, back to original pixels
        helper.make_node("Slice", [pc, "p_s", "p_e", "p_ax"], ["p0"]),
        helper.make_node("Reshape", ["p0", "shape2"], ["p0f"]),
        helper.make_node("Mul", ["p0f", "ratio_xy"], ["pxy0"]),
        helper.make_node("Add", ["pxy0", "offset"], ["pxy"]),
        helper.make_node("Gather", ["pxy", "i0"], ["px"], axis=0),
        helper.make_node("Gather", ["pxy", "i1"], ["py"], axis=0),
        helper.make_node("Gather", [osz, "i0"], ["h"], axis=0),
        helper.make_node("Gather", [osz, "i1"], ["w"], axis=0),
        helper.make_node("Range", ["zero", "h", "one"], ["rows"]),
        helper.make_node("Range", ["zero", "w", "one"], ["cols"]),
    ]
    dn, di, logits = _disc_nodes("px", "py", "rows", "cols", radii, slopes, "m_")
    nodes += dn
    inits += di
    nodes += [
        helper.make_node("Unsqueeze", [logits, "ax0"], ["masks"]),
        *_touch_inputs([emb, pl, mi, hm], "s_zero"),
        helper.make_node("Mul", ["px", "iou_slope"], ["iou_u"]),
        helper.make_node("Add", ["iou_base", "iou_u"], ["iou_a"]),
        helper.make_node("Add", ["iou_a", "s_zero"], ["iou_predictions"]),
        helper.make_node("Identity", ["lowres"], ["low_res_masks"]),
    ]
    graph = helper.make_graph(
        nodes, "sam_decoder",
        [helper.make_tensor_value_info(emb, TensorProto.FLOAT, [1, 256, 64, 64]),
         helper.make_tensor_value_info(pc, TensorProto.FLOAT, [1, "num_points", 2]),
         helper.make_tensor_value_info(pl, TensorProto.FLOAT, [1, "num_points"]),
         helper.make_tensor_value_info(mi, TensorProto.FLOAT, [1, 1, 256, 256]),
         helper.make_tensor_value_info(hm, TensorProto.FLOAT, [1]),
         helper.make_tensor_value_info(osz, TensorProto.FLOAT, [2])],
        [helper.make_tensor_value_info("masks", TensorProto.FLOAT, [1, c, "H", "W"]),
         helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, c]),
         helper.make_tensor_value_info("low_res_masks", TensorProto.FLOAT, [1, c, 256, 256])],
        inits)
    return _save(graph, path)


# ---------------------------------------------------------- EfficientSAM
def efficientsam_encoder(path) -> Path:
    """``batched_images`` (1,3,H,W) in [0,1] -> ``image_embeddings`` (1,256,64,64)."""
    nodes = [
        helper.make_node("Resize", ["batched_images", "", "", "sizes"], ["r"], mode="linear"),
        helper.make_node("AveragePool", ["r"], ["pooled"], kernel_shape=[16, 16], strides=[16, 16]),
        helper.make_node("Tile", ["pooled", "reps"], ["tiled"]),
        helper.make_node("Slice", ["tiled", "s0", "s1", "sax"], ["image_embeddings"]),
    ]
    graph = helper.make_graph(
        nodes, "esam_encoder",
        [helper.make_tensor_value_info("batched_images", TensorProto.FLOAT, [1, 3, "H", "W"])],
        [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])],
        [_const("sizes", np.array([1, 3, 1024, 1024], np.int64)),
         _const("reps", np.array([1, 86, 1, 1], np.int64)), _const("s0", np.array([0], np.int64)),
         _const("s1", np.array([256], np.int64)), _const("sax", np.array([1], np.int64))])
    return _save(graph, path)


def efficientsam_decoder(path, radii: Sequence[float] = (4.0, 10.5, 20.5),
                         slopes: Sequence[float] = (0.2, 30.0, 30.0),
                         ious: Sequence[float] = (0.99, 0.9, 0.8),
                         iou_slope_u: float = 1e-4) -> Path:
    """EfficientSAM decoder contract: (1,Q,P,2) original-pixel points -> (1,Q,C,H,W) discs."""
    c = len(radii)
    inits = [
        _const("zero", np.array(0.0, np.float32)), _const("one", np.array(1.0, np.float32)),
        _const("i0", np.array(0, np.int64)), _const("i1", np.array(1, np.int64)),
        _const("ax0", np.array([0], np.int64)), _const("ax1", np.array([1], np.int64)),
        _const("ax2", np.array([2], np.int64)),
        _const("K", np.asarray(slopes, np.float32).reshape(1, c, 1, 1)),
        _const("R", np.asarray(radii, np.float32).reshape(1, c, 1, 1)),
        _const("iou_base", np.asarray(ious, np.float32).reshape(1, 1, c)),
        _const("iou_slope", np.array(iou_slope_u, np.float32)),
    ]
    nodes = [
        helper.make_node("Cast", ["orig_im_size"], ["osz"], to=TensorProto.FLOAT),
        helper.make_node("Gather", ["osz", "i0"], ["h"], axis=0),
        helper.make_node("Gather", ["osz", "i1"], ["w"], axis=0),
        helper.make_node("Range", ["zero", "h", "one"], ["rows"]),
        helper.make_node("Range", ["zero", "w", "one"], ["cols"]),
        # first point of each query: (1,Q,P,2) -> (Q,)
        helper.make_node("Gather", ["batched_point_coords", "i0"], ["q_pts"], axis=0),  # (Q,P,2)
        helper.make_node("Gather", ["q_pts", "i0"], ["q_p0"], axis=1),                  # (Q,2)
        helper.make_node("Gather", ["q_p0", "i0"], ["px"], axis=1),                     # (Q,)
        helper.make_node("Gather", ["q_p0", "i1"], ["py"], axis=1),
        helper.make_node("Unsqueeze", ["px", "ax1"], ["pxc"]),                          # (Q,1)
        helper.make_node("Unsqueeze", ["py", "ax1"], ["pyc"]),
        helper.make_node("Sub", ["cols", "pxc"], ["dx"]),                               # (Q,W)
        helper.make_node("Sub", ["rows", "pyc"], ["dy"]),                               # (Q,H)
        helper.make_node("Mul", ["dx", "dx"], ["dx2"]),
        helper.make_node("Mul", ["dy", "dy"], ["dy2"]),
        helper.make_node("Unsqueeze", ["dx2", "ax1"], ["dx2q"]),                        # (Q,1,W)
        helper.make_node("Unsqueeze", ["dy2", "ax2"], ["dy2q"]),                        # (Q,H,1)
        helper.make_node("Add", ["dx2q", "dy2q"], ["d2"]),
        helper.make_node("Sqrt", ["d2"], ["d"]),
        helper.make_node("Unsqueeze", ["d", "ax1"], ["d4"]),                            # (Q,1,H,W)
        helper.make_node("Sub", ["R", "d4"], ["rd"]),
        helper.make_node("Mul", ["K", "rd"], ["lg"]),                                   # (Q,C,H,W)
        helper.make_node("Unsqueeze", ["lg", "ax0"], ["output_masks"]),
        helper.make_node("Mul", ["px", "iou_slope"], ["iu"]),                           # (Q,)
        helper.make_node("Unsqueeze", ["iu", "ax0"], ["iu1"]),                          # (1,Q)
        helper.make_node("Unsqueeze", ["iu1", "ax2"], ["iu2"]),                         # (1,Q,1)
        *_touch_inputs(["image_embeddings", "batched_point_labels"], "s_zero"),
        helper.make_node("Add", ["iou_base", "iu2"], ["iou_a"]),
        helper.make_node("Add", ["iou_a", "s_zero"], ["iou_predictions"]),
        helper.make_node("Identity", ["lg"], ["low_res_logits"]),
    ]
    graph = helper.make_graph(
        nodes, "esam_decoder",
        [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64]),
         helper.make_tensor_value_info("batched_point_coords", TensorProto.FLOAT,
                                       [1, "Q", "P", 2]),
         helper.make_tensor_value_info("batched_point_labels", TensorProto.FLOAT, [1, "Q", "P"]),
         helper.make_tensor_value_info("orig_im_size", TensorProto.INT64, [2])],
        [helper.make_tensor_value_info("output_masks", TensorProto.FLOAT,
                                       [1, "Q", c, "H", "W"]),
         helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, "Q", c]),
         helper.make_tensor_value_info("low_res_logits", TensorProto.FLOAT, ["Q", c, "H", "W"])],
        inits)
    return _save(graph, path)


# ---------------------------------------------------------------- normals
def normal_model(path, input_size=(48, 64), mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0),
                 scale: float = 1.0, input_name: str = "image", output_name: str = "normals",
                 confidence: Optional[float] = None, confidence_output: Optional[str] = None,
                 output_layout: str = "NCHW", raw_rgb: bool = False,
                 input_layout: str = "NCHW") -> Path:
    """Decode the (normalised) input image as colour-coded normals.

    ``rgb = (x * std + mean) / scale`` undoes the front-end normalisation
    (``scale`` = 255 for 0-255 input), the output is ``2 * rgb - 1`` (NCHW or
    NHWC).  ``confidence`` appends a constant 4th channel; ``confidence_output``
    instead adds a separate (1,1,h,w) output with that name.  ``raw_rgb``
    outputs ``rgb`` itself (a model whose output is colour-coded in [0, 1]).
    ``input_layout="NHWC"`` takes a (1,h,w,3) input.
    """
    h, w = input_size if input_size is not None else ("h", "w")
    inits = [_const("mean", np.asarray(mean, np.float32).reshape(1, 3, 1, 1)),
             _const("std", np.asarray(std, np.float32).reshape(1, 3, 1, 1)),
             _const("inv_scale", np.array(1.0 / scale, np.float32))]
    nodes = []
    x = input_name
    if input_layout == "NHWC":
        nodes.append(helper.make_node("Transpose", [input_name], ["x_nchw"], perm=[0, 3, 1, 2]))
        x = "x_nchw"
    nodes += [helper.make_node("Mul", [x, "std"], ["a"]),
              helper.make_node("Add", ["a", "mean"], ["b"]),
              helper.make_node("Mul", ["b", "inv_scale"], ["rgb"])]
    if raw_rgb:
        nodes.append(helper.make_node("Identity", ["rgb"], ["n3"]))
    else:
        inits += [_const("two", np.array(2.0, np.float32)),
                  _const("one", np.array(1.0, np.float32))]
        nodes += [helper.make_node("Mul", ["rgb", "two"], ["c"]),
                  helper.make_node("Sub", ["c", "one"], ["n3"])]
    outputs = []
    out_c = 3
    n_out = "n3"
    conf_name = None
    if confidence is not None:
        inits += [_const("conf", np.array(confidence, np.float32)),
                  _const("zero", np.array(0.0, np.float32)),
                  _const("s0", np.array([0], np.int64)), _const("s1", np.array([1], np.int64)),
                  _const("sax", np.array([1], np.int64))]
        nodes += [helper.make_node("Slice", ["n3", "s0", "s1", "sax"], ["ch0"]),
                  helper.make_node("Mul", ["ch0", "zero"], ["ch0z"]),
                  helper.make_node("Add", ["ch0z", "conf"], ["confmap"])]
        if confidence_output:
            conf_name = confidence_output
        else:
            nodes.append(helper.make_node("Concat", ["n3", "confmap"], ["n4"], axis=1))
            n_out, out_c = "n4", 4
    perm = [0, 2, 3, 1]
    if output_layout == "NHWC":
        nodes.append(helper.make_node("Transpose", [n_out], [output_name], perm=perm))
        outputs.append(helper.make_tensor_value_info(output_name, TensorProto.FLOAT,
                                                     [1, h, w, out_c]))
    else:
        nodes.append(helper.make_node("Identity", [n_out], [output_name]))
        outputs.append(helper.make_tensor_value_info(output_name, TensorProto.FLOAT,
                                                     [1, out_c, h, w]))
    if conf_name:
        nodes.append(helper.make_node("Identity", ["confmap"], [conf_name]))
        outputs.append(helper.make_tensor_value_info(conf_name, TensorProto.FLOAT, [1, 1, h, w]))
    graph = helper.make_graph(
        nodes, "normals",
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT,
                                       [1, 3, h, w] if input_layout == "NCHW" else [1, h, w, 3])],
        outputs, inits)
    return _save(graph, path)


def encode_normals(normals: np.ndarray) -> np.ndarray:
    """Colour-code unit normals (..., 3) as an RGB image in [0, 1]."""
    return np.clip((np.asarray(normals, np.float64) + 1.0) / 2.0, 0.0, 1.0).astype(np.float32)


# ------------------------------------------------------------------ depth
def depth_model(path, coeffs=(0.0, 0.0, 1.0), kind: str = "inverse", input_size=None,
                mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0), scale: float = 1.0,
                gain: float = 1.0, output_rank: int = 3, channels: int = 1,
                input_rank: int = 4, input_name: str = "pixel_values",
                output_name: str = "predicted_depth", in_channels: int = 3) -> Path:
    """A monocular depth network contract whose output is a known plane.

    For an input of (any, unless ``input_size``) size h x w, with normalised
    coordinates ``x = (j + 0.5) / w``, ``y = (i + 0.5) / h`` (the pixel-centre
    mapping of a stretch resize, so ``x = (u + 0.5) / W`` in the image), the
    inverse depth is ``q = a x + b y + c`` (``coeffs = (a, b, c)``) plus
    ``gain * (mean over channels of rgb - 0.5)``, ``rgb = (x_in * std + mean) /
    scale`` undoing the front-end normalisation.  ``kind`` ``"inverse"``
    outputs ``q``, ``"depth"`` outputs ``1 / q``.  Output (1, h, w)
    (``output_rank=3``) or (1, channels, h, w) (``output_rank=4``).
    ``input_rank=3`` declares a (3, h, w) input and ``in_channels`` other than 3 an
    input of that many channels (broken contracts).
    """
    h, w = input_size if input_size is not None else ("h", "w")
    a, b, c = (float(v) for v in coeffs)
    inits = [_const("mean", np.asarray(mean, np.float32).reshape(1, 3, 1, 1)),
             _const("std", np.asarray(std, np.float32).reshape(1, 3, 1, 1)),
             _const("inv_scale", np.array(1.0 / scale, np.float32)),
             _const("half", np.array(0.5, np.float32)), _const("zero", np.array(0.0, np.float32)),
             _const("one", np.array(1.0, np.float32)), _const("gain", np.array(gain, np.float32)),
             _const("ca", np.array(a, np.float32)), _const("cb", np.array(b, np.float32)),
             _const("cc", np.array(c, np.float32)),
             _const("i2", np.array(2, np.int64)), _const("i3", np.array(3, np.int64)),
             _const("ax0", np.array([0], np.int64)), _const("ax1", np.array([1], np.int64))]
    nodes = []
    x = input_name
    if input_rank == 3:
        nodes.append(helper.make_node("Unsqueeze", [input_name, "ax0"], ["x4"]))
        x = "x4"
    nodes += [
        helper.make_node("Shape", [x], ["shp"]),
        helper.make_node("Gather", ["shp", "i2"], ["h_i"], axis=0),
        helper.make_node("Gather", ["shp", "i3"], ["w_i"], axis=0),
        helper.make_node("Cast", ["h_i"], ["h_f"], to=TensorProto.FLOAT),
        helper.make_node("Cast", ["w_i"], ["w_f"], to=TensorProto.FLOAT),
        helper.make_node("Range", ["zero", "h_f", "one"], ["rows0"]),
        helper.make_node("Range", ["zero", "w_f", "one"], ["cols0"]),
        helper.make_node("Add", ["rows0", "half"], ["rows1"]),
        helper.make_node("Add", ["cols0", "half"], ["cols1"]),
        helper.make_node("Div", ["rows1", "h_f"], ["yn"]),                     # (h,)
        helper.make_node("Div", ["cols1", "w_f"], ["xn"]),                     # (w,)
        helper.make_node("Mul", ["xn", "ca"], ["ax_"]),
        helper.make_node("Mul", ["yn", "cb"], ["by_"]),
        helper.make_node("Unsqueeze", ["by_", "ax1"], ["by_c"]),              # (h,1)
        helper.make_node("Unsqueeze", ["ax_", "ax0"], ["ax_r"]),              # (1,w)
        helper.make_node("Add", ["by_c", "ax_r"], ["plane0"]),
        helper.make_node("Add", ["plane0", "cc"], ["plane"]),                 # (h,w)
        helper.make_node("Mul", [x, "std"], ["s1"]),
        helper.make_node("Add", ["s1", "mean"], ["s2"]),
        helper.make_node("Mul", ["s2", "inv_scale"], ["rgb"]),
        helper.make_node("ReduceMean", ["rgb"], ["grey"], axes=[1], keepdims=1),  # (1,1,h,w)
        helper.make_node("Sub", ["grey", "half"], ["dev"]),
        helper.make_node("Mul", ["dev", "gain"], ["term"]),
        helper.make_node("Add", ["plane", "term"], ["q"]),                     # (1,1,h,w)
    ]
    out = "q"
    if kind == "depth":
        nodes.append(helper.make_node("Reciprocal", ["q"], ["z"]))
        out = "z"
    if channels != 1:
        nodes.append(helper.make_node("Concat", [out] * channels, ["multi"], axis=1))
        out = "multi"
    if output_rank == 3:
        nodes.append(helper.make_node("Squeeze", [out, "ax1"], [output_name]))
        out_shape = [1, h, w]
    else:
        nodes.append(helper.make_node("Identity", [out], [output_name]))
        out_shape = [1, channels, h, w]
    in_shape = [1, in_channels, h, w] if input_rank == 4 else [in_channels, h, w]
    graph = helper.make_graph(
        nodes, "depth",
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, in_shape)],
        [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, out_shape)], inits)
    return _save(graph, path)
