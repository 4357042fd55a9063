"""Export a forest to ONNX: the whole per-pixel classifier as one graph for onnxruntime.

Graph (opset 17), the same arithmetic as the torch backend (``runtime/forest/inference.py``)::

    inputs   depth (H, W) float32 metres (0 = no reading), mask (H, W) bool person mask,
             offset_scale (2,) float32 (fx'/fx, fy'/fy; [1, 1] at the trained camera),
             node_table (Nn, 8) float32 (shared.forest_format.traversal_table),
             leaf_dist (L, C) float16, roots (T,) int64
    outputs  posteriors (N, C) float32, labels (N,) int64, pixels (N, 2) int64 (row, col)
             for the N pixels of ``mask`` with a reading, in row-major order

1. valid = mask & depth > 0; D = depth where valid else the background constant; D is padded
   by one background pixel on every side; the valid pixels are listed with NonZero.
2. ``max_depth`` unrolled steps, each: Gather the node rows of all (pixel, tree) pairs, probe
   coordinates ``floor(min(max(u * (s / D(x)) + (x + 1.5), 0), W + 1))``, Gather the two probe
   depths from the flattened padded image, ``f > threshold`` picks the right child, else the
   left. Leaves point to themselves (zero offsets, threshold +inf), so extra steps are harmless.
3. Gather the leaf distributions, mean over trees, ArgMax.

Two flavours: :func:`export_onnx` writes a standalone ``.onnx`` whose tables are initializers
(``offset_scale`` stays an input with default [1, 1]); :func:`embedded_graph` returns the graph
with the tables as inputs, a few kilobytes, which ``train-forest`` stores in ``forest.npz`` so
that the runtime's onnxruntime backend needs neither the ``onnx`` package nor a second file.
The feature computation is inside the graph: callers feed raw depth and the mask.

``python -m depthmocap.train.forest.onnx_export forest.npz forest.onnx`` writes the standalone file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared.forest_format import Forest, ForestFormatError, load_forest, traversal_table

__all__ = ["OPSET", "build_model", "export_onnx", "embedded_graph", "main"]

OPSET = 17


def build_model(forest: Forest, embed_tables: bool):
    """The ONNX ModelProto of ``forest`` (see the module docstring)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    levels = forest.max_depth
    nodes: list = []
    inits: list = []

    def const(name: str, value, dtype=np.float32) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(kind: str, inputs: list[str], name: str, **attrs) -> str:
        nodes.append(helper.make_node(kind, inputs, [name], name=name, **attrs))
        return name

    bg = const("background", forest.background_m)
    zero = const("zero", 0.0)
    one_five = const("one_five", 1.5)
    i64 = np.int64
    const("pads", [1, 1, 1, 1], i64)
    const("flat_shape", [-1], i64)
    const("col_row", [1, 0], i64)
    const("axis0", [0], i64)
    const("axis1", [1], i64)
    const("axis2", [2], i64)
    for name, value in {
        "c0": 0,
        "c1": 1,
        "c2": 2,
        "c4": 4,
        "c5": 5,
        "c6": 6,
        "c7": 7,
        "c8": 8,
    }.items():
        const(name, [value], i64)
    const("one_f", 1.0)
    const("two_f", 2.0)

    # Person depth, padded and flattened; hi4 = (W + 1, H + 1, W + 1, H + 1).
    valid = op("And", ["mask", op("Greater", ["depth", zero], "has_depth")], "valid")
    person = op("Where", [valid, "depth", bg], "person")
    padded = op("Pad", [person, "pads", bg], "padded", mode="constant")
    flat = op("Reshape", [padded, "flat_shape"], "flat")
    hw = op("Cast", [op("Shape", ["depth"], "hw_i")], "hw", to=TensorProto.FLOAT)
    wh1 = op("Add", [op("Gather", [hw, "col_row"], "wh", axis=0), "one_f"], "wh1")
    hi4 = op("Concat", [wh1, wh1], "hi4", axis=0)
    wp = op("Add", [op("Gather", [hw, "c1"], "w_1", axis=0), "two_f"], "wp")  # (1,)
    # Valid pixels, their depth, base coordinates and inverse depth.
    pixels = op("Transpose", [op("NonZero", [valid], "nz")], "pixels_rc", perm=[1, 0])
    dx = op("GatherND", ["depth", pixels], "dx")
    pf = op("Cast", [pixels], "pix_f", to=TensorProto.FLOAT)
    base2 = op("Add", [op("Gather", [pf, "col_row"], "xy", axis=1), one_five], "base2")
    base4 = op("Unsqueeze", [op("Concat", [base2, base2], "base4_", axis=1), "axis1"], "base4")
    scale = op("Unsqueeze", ["offset_scale", "axis0"], "scale_row")
    invd2 = op("Div", [scale, op("Unsqueeze", [dx, "axis1"], "dx_col")], "invd2")
    invd4 = op("Unsqueeze", [op("Concat", [invd2, invd2], "invd4_", axis=1), "axis1"], "invd4")
    # (N, T) pairs start at the roots.
    n = op("Gather", [op("Shape", [dx], "n_shape"), "c0"], "n", axis=0)  # (1,)
    t = op("Shape", ["roots"], "t")
    pair_shape = op("Concat", [n, t], "pair_shape", axis=0)
    node = op("Expand", [op("Unsqueeze", ["roots", "axis0"], "roots_row"), pair_shape], "node0")
    for level in range(levels):
        p = f"l{level}_"
        row = op("Gather", ["node_table", node], p + "row", axis=0)  # (N, T, 8)
        uv = op("Slice", [row, "c0", "c4", "axis2"], p + "uv")
        thr = op("Slice", [row, "c4", "c5", "axis2"], p + "thr")
        left = op("Slice", [row, "c5", "c6", "axis2"], p + "left")
        right = op("Slice", [row, "c6", "c7", "axis2"], p + "right")
        c = op("Add", [op("Mul", [uv, invd4], p + "off"), base4], p + "c_raw")
        c = op("Floor", [op("Min", [op("Max", [c, zero], p + "c_lo"), hi4], p + "c_hi")], p + "c")
        cx = op("Slice", [c, "c0", "c4", "axis2", "c2"], p + "cx")
        cy = op("Slice", [c, "c1", "c4", "axis2", "c2"], p + "cy")
        lin = op("Add", [op("Mul", [cy, wp], p + "row_off"), cx], p + "lin_f")
        lin = op("Cast", [lin], p + "lin", to=TensorProto.INT64)
        d = op("Gather", [flat, lin], p + "d", axis=0)  # (N, T, 2)
        f = op("Sub", [op("Slice", [d, "c0", "c1", "axis2"], p + "d0"),
                       op("Slice", [d, "c1", "c2", "axis2"], p + "d1")], p + "f")  # fmt: skip
        nxt = op("Where", [op("Greater", [f, thr], p + "gt"), right, left], p + "next_f")
        nxt = op("Squeeze", [nxt, "axis2"], p + "next_sq")
        node = op("Cast", [nxt], p + "node", to=TensorProto.INT64)
    row = op("Gather", ["node_table", node], "leaf_row", axis=0)
    leaf = op("Squeeze", [op("Slice", [row, "c7", "c8", "axis2"], "leaf_f3"), "axis2"], "leaf_f")
    leaf = op("Cast", [leaf], "leaf", to=TensorProto.INT64)
    dist = op("Cast", [op("Gather", ["leaf_dist", leaf], "dist16", axis=0)], "dist", to=1)
    nodes.append(
        helper.make_node("ReduceMean", [dist], ["posteriors"], name="mean", axes=[1], keepdims=0)
    )
    nodes.append(
        helper.make_node("ArgMax", ["posteriors"], ["labels"], name="argmax", axis=1, keepdims=0)
    )
    nodes.append(helper.make_node("Identity", [pixels], ["pixels"], name="pixels_out"))

    c_ = forest.num_classes
    inputs = [
        helper.make_tensor_value_info("depth", TensorProto.FLOAT, ["H", "W"]),
        helper.make_tensor_value_info("mask", TensorProto.BOOL, ["H", "W"]),
        helper.make_tensor_value_info("offset_scale", TensorProto.FLOAT, [2]),
    ]
    tables = {
        "node_table": traversal_table(forest),
        "leaf_dist": forest.leaf_dist.astype(np.float16),
        "roots": forest.roots.astype(np.int64),
    }
    if embed_tables:
        inits.extend(numpy_helper.from_array(v, k) for k, v in tables.items())
        inits.append(numpy_helper.from_array(np.ones(2, np.float32), "offset_scale"))
    else:
        inputs += [
            helper.make_tensor_value_info("node_table", TensorProto.FLOAT, ["nodes", 8]),
            helper.make_tensor_value_info("leaf_dist", TensorProto.FLOAT16, ["leaves", c_]),
            helper.make_tensor_value_info("roots", TensorProto.INT64, ["trees"]),
        ]
    outputs = [
        helper.make_tensor_value_info("posteriors", TensorProto.FLOAT, ["N", c_]),
        helper.make_tensor_value_info("labels", TensorProto.INT64, ["N"]),
        helper.make_tensor_value_info("pixels", TensorProto.INT64, ["N", 2]),
    ]
    graph = helper.make_graph(nodes, "depthmocap_forest", inputs, outputs, initializer=inits)
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="depthmocap train-forest",
        doc_string=f"per-pixel body-part forest: {forest.num_trees} trees, depth {levels}, "
        f"classes {','.join(forest.class_names)}",
    )
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def embedded_graph(forest: Forest) -> bytes:
    """Serialized graph with the tables as inputs (stored inside ``forest.npz``)."""
    return build_model(forest, embed_tables=False).SerializeToString()


def export_onnx(forest: Forest, path: str | Path) -> None:
    """Write a standalone ``.onnx`` file (tables as initializers)."""
    Path(path).write_bytes(build_model(forest, embed_tables=True).SerializeToString())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Export forest.npz to a standalone ONNX file.")
    parser.add_argument("model", help="forest.npz")
    parser.add_argument("out", help="output .onnx")
    args = parser.parse_args(argv)
    try:
        export_onnx(load_forest(args.model), args.out)
    except (ForestFormatError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
