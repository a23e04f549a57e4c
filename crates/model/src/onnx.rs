//! The network as an ONNX model (`hive export`, `QNetwork.to_onnx`), for
//! any runtime that reads ONNX (onnxruntime, TensorRT, OpenVINO, a browser).
//!
//! Inputs `depth` `(B, frames, 32, 32)` and `velocity` `(B, scalars)` (the
//! velocity, 3; with a goal, the velocity then the goal's 3), then, with the
//! camera's map, `map` `(B, floats)` (joined after the velocity), output `q`
//! `(B, actions)`: conv 6×6/2 → ReLU → conv 3×3 → ReLU → max-pool 2 → flatten;
//! velocity → Gemm → ReLU; concatenated → (Gemm → ReLU) for each hidden
//! layer (`fc1`, then `fc1b`, `fc1c`) → Gemm. The weights go
//! in ONNX's (PyTorch's) layout: conv2's `(out, kh, kw, in)` becomes
//! `(out, in, kh, kw)` and fc1's pooled columns `(y, x, c)` become
//! `(c, y, x)`, as `rotorhive.net.torch_layout` does.
//!
//! The protobuf is written by hand through `rotorhive_msg::protobuf` (a few
//! message types, no crate needed: the `onnx` crates on crates.io carry
//! whole generated schemas and a protobuf runtime for what is here about a
//! hundred lines); onnxruntime and `onnx.checker` read it back in the
//! Python tests.

use std::collections::HashMap;

use candle_core::Tensor;
use rotorhive_msg::protobuf::{bytes, int};

use crate::layers::Geometry;
use crate::layers::HIDDEN_NAMES;
use crate::{K1, K2, Layers, Result, S1, Shapes, params};

/// The IR version written (ONNX 1.14 and later read it).
const IR_VERSION: u64 = 9;
/// The operator set (every operator used exists since 13).
const OPSET: u64 = 17;

/// The ONNX model of weights given by name (as [`crate::QNet::named`], or
/// [`crate::RecurrentQNet::named`] with its GRU's `width`), with `metadata`
/// as its metadata properties. A recurrent model also takes `state` `(B,
/// width)` and gives `next_state` (ONNX names a value once, so the state
/// out cannot be called `state` too): the trunk's `fc1` activations go
/// through ONNX's `GRU` (gates reordered to its z, r, h; PyTorch's
/// `linear_before_reset`), the Q head reads the new state.
pub(crate) fn model(
    named: &HashMap<String, Tensor>,
    shapes: Shapes,
    layers: Layers,
    width: Option<usize>,
    metadata: &[(String, String)],
) -> Result<Vec<u8>> {
    let mut weights: HashMap<&str, Vec<f32>> = HashMap::new();
    let names = match width {
        Some(w) => crate::recurrent_params(shapes, layers, w),
        None => params(shapes, layers),
    };
    for (name, _) in &names {
        weights.insert(name, named[*name].flatten_all()?.to_vec1::<f32>()?);
    }
    let (conv2, fc1) =
        torch_layout(&weights["conv2.weight"], &weights["fc1.weight"], layers, shapes);
    let mut graph = Vec::new();
    for n in nodes(layers, width, [shapes.map > 0, shapes.tracks > 0]) {
        bytes(&mut graph, 1, &n);
    }
    bytes(&mut graph, 2, b"rotorhive_qnet");
    let [c1, c2] = layers.conv();
    for (name, shape) in &names {
        let dims = match *name {
            "conv1.weight" => vec![c1, shapes.frames, K1, K1],
            "conv2.weight" => vec![c2, c1, K2, K2],
            _ => shape.clone(),
        };
        let data = match *name {
            "conv2.weight" => &conv2,
            "fc1.weight" => &fc1,
            _ => &weights[name],
        };
        if !name.starts_with("gru.") {
            bytes(&mut graph, 5, &tensor(name, &dims, data));
        }
    }
    if let Some(w) = width {
        for t in gru_initializers(&weights, w, layers.out()) {
            bytes(&mut graph, 5, &t);
        }
    }
    for (field, info) in inputs_and_outputs(shapes, width) {
        bytes(&mut graph, field, &info);
    }

    let mut m = Vec::new();
    int(&mut m, 1, IR_VERSION);
    bytes(&mut m, 2, b"rotorhive");
    bytes(&mut m, 7, &graph);
    let mut opset = Vec::new();
    bytes(&mut opset, 1, b"");
    int(&mut opset, 2, OPSET);
    bytes(&mut m, 8, &opset);
    for (k, v) in metadata {
        let mut entry = Vec::new();
        bytes(&mut entry, 1, k.as_bytes());
        bytes(&mut entry, 2, v.as_bytes());
        bytes(&mut m, 14, &entry);
    }
    Ok(m)
}

/// The graph's inputs (field 11: depth, velocity, then map, tracks and
/// state where the network has them) and outputs (field 12: q, then
/// next_state for a recurrent one), each as its `ValueInfoProto`.
fn inputs_and_outputs(shapes: Shapes, width: Option<usize>) -> Vec<(u32, Vec<u8>)> {
    let depth = [None, Some(shapes.frames), Some(shapes.depth[0]), Some(shapes.depth[1])];
    let mut infos = vec![
        (11, value_info("depth", &depth)),
        (11, value_info("velocity", &[None, Some(shapes.scalars - shapes.memory_floats())])),
    ];
    if shapes.map > 0 {
        infos.push((11, value_info("map", &[None, Some(shapes.map)])));
    }
    if shapes.tracks > 0 {
        infos.push((11, value_info("tracks", &[None, Some(shapes.tracks)])));
    }
    if let Some(w) = width {
        infos.push((11, value_info("state", &[None, Some(w)])));
    }
    infos.push((12, value_info("q", &[None, Some(shapes.actions)])));
    if let Some(w) = width {
        infos.push((12, value_info("next_state", &[None, Some(w)])));
    }
    infos
}

/// The GRU's initializers in ONNX's layout (PyTorch's gate blocks r, z, n
/// become ONNX's z, r, h; both biases in one `B`), and the axis the
/// `Unsqueeze` nodes take.
fn gru_initializers(weights: &HashMap<&str, Vec<f32>>, w: usize, input: usize) -> [Vec<u8>; 4] {
    let zrh = |v: &[f32]| -> Vec<f32> {
        let k = v.len() / 3;
        [&v[k..2 * k], &v[..k], &v[2 * k..]].concat()
    };
    let b = [zrh(&weights["gru.bias_ih"]), zrh(&weights["gru.bias_hh"])].concat();
    [
        tensor("gru.W", &[1, 3 * w, input], &zrh(&weights["gru.weight_ih"])),
        tensor("gru.R", &[1, 3 * w, w], &zrh(&weights["gru.weight_hh"])),
        tensor("gru.B", &[1, 6 * w], &b),
        int64s("axis0", &[0]),
    ]
}

/// conv2's `(out, kh, kw, in)` as `(out, in, kh, kw)`, and fc1's pooled
/// columns `(y, x, c)` as `(c, y, x)`: PyTorch's (ONNX's) layouts.
fn torch_layout(
    conv2: &[f32],
    fc1: &[f32],
    layers: Layers,
    shapes: Shapes,
) -> (Vec<f32>, Vec<f32>) {
    let [c1, c2] = layers.conv();
    let conv2: Vec<f32> = (0..c2 * c1 * K2 * K2)
        .map(|i| {
            let (o, rest) = (i / (c1 * K2 * K2), i % (c1 * K2 * K2));
            let (c, ky, kx) = (rest / (K2 * K2), rest % (K2 * K2) / K2, rest % K2);
            conv2[((o * K2 + ky) * K2 + kx) * c1 + c]
        })
        .collect();
    let (cols, pooled) = (layers.features(shapes), layers.pooled(shapes));
    let g = Geometry::of(shapes);
    let cells = g.cells_pooled();
    let fc1: Vec<f32> = (0..layers.hidden()[0] * cols)
        .map(|i| {
            let (r, j) = (i / cols, i % cols);
            if j >= pooled {
                return fc1[r * cols + j];
            }
            let (c, y, x) = (j / cells, j % cells / g.wp, j % g.wp);
            fc1[r * cols + (y * g.wp + x) * c2 + c]
        })
        .collect();
    (conv2, fc1)
}

/// The graph's nodes, in order: the Q head on `fc1`'s activations, or
/// (with a GRU of `width`) on the GRU's new state.
fn nodes(layers: Layers, width: Option<usize>, memory: [bool; 2]) -> Vec<Vec<u8>> {
    let mut all = trunk_nodes(layers, memory);
    let Some(width) = width else {
        all.push(node("Gemm", &["h", "fc2.weight", "fc2.bias"], "q", &[], Some(("transB", 1))));
        return all;
    };
    all.extend([
        node("Unsqueeze", &["h", "axis0"], "x", &[], None),
        node("Unsqueeze", &["state", "axis0"], "h0", &[], None),
        gru(width),
        // Y (1, 1, B, W) → (B, W).
        node("Flatten", &["y"], "next_state", &[], Some(("axis", 3))),
        node("Gemm", &["next_state", "fc2.weight", "fc2.bias"], "q", &[], Some(("transB", 1))),
    ]);
    all
}

/// The `GRU` node: one step of `x` from `h0` with PyTorch's gate
/// arithmetic (`linear_before_reset`), output `y`.
fn gru(width: usize) -> Vec<u8> {
    let mut n = node(
        "GRU",
        &["x", "gru.W", "gru.R", "gru.B", "", "h0"],
        "y",
        &[],
        Some(("linear_before_reset", 1)),
    );
    bytes(&mut n, 5, &int_attr("hidden_size", width as i64));
    n
}

/// The trunk's nodes, up to the last hidden layer's activations `h`.
fn trunk_nodes(layers: Layers, [map, tracks]: [bool; 2]) -> Vec<Vec<u8>> {
    let mut all = vec![
        node(
            "Conv",
            &["depth", "conv1.weight", "conv1.bias"],
            "c1",
            &[("kernel_shape", &[K1, K1]), ("strides", &[S1, S1])],
            None,
        ),
        node("Relu", &["c1"], "r1", &[], None),
        node(
            "Conv",
            &["r1", "conv2.weight", "conv2.bias"],
            "c2",
            &[("kernel_shape", &[K2, K2])],
            None,
        ),
        node("Relu", &["c2"], "r2", &[], None),
        node("MaxPool", &["r2"], "p", &[("kernel_shape", &[2, 2]), ("strides", &[2, 2])], None),
        node("Flatten", &["p"], "features", &[], Some(("axis", 1))),
    ];
    // With the camera's map or the seen movers, the scalars' branch reads
    // the velocity (and goal), then the map, then the tracks, joined.
    let parts: Vec<&str> = [("velocity", true), ("map", map), ("tracks", tracks)]
        .into_iter()
        .filter_map(|(name, on)| on.then_some(name))
        .collect();
    let scalars = if parts.len() > 1 {
        all.push(node("Concat", &parts, "scalars", &[], Some(("axis", 1))));
        "scalars"
    } else {
        "velocity"
    };
    all.extend([
        node("Gemm", &[scalars, "vel.weight", "vel.bias"], "v1", &[], Some(("transB", 1))),
        node("Relu", &["v1"], "v", &[], None),
        node("Concat", &["features", "v"], "joined", &[], Some(("axis", 1))),
    ]);
    // The hidden layers: `fc1` reads the joined features, each next one
    // the layer before; the last one's activations are `h`.
    let depth = layers.hidden().len();
    let mut input = "joined".to_string();
    for (k, [w, b]) in HIDDEN_NAMES.iter().enumerate().take(depth) {
        let out = if k + 1 == depth { "h".to_string() } else { format!("a{}", k + 1) };
        let pre = format!("h{}", k + 1);
        all.push(node("Gemm", &[&input, w, b], &pre, &[], Some(("transB", 1))));
        all.push(node("Relu", &[&pre], &out, &[], None));
        input = out;
    }
    all
}

/// A `NodeProto`: inputs, one output, the operator, `ints` attributes and
/// at most one `int` attribute.
fn node(
    op: &str,
    inputs: &[&str],
    output: &str,
    ints: &[(&str, &[usize])],
    one: Option<(&str, i64)>,
) -> Vec<u8> {
    let mut n = Vec::new();
    for i in inputs {
        bytes(&mut n, 1, i.as_bytes());
    }
    bytes(&mut n, 2, output.as_bytes());
    bytes(&mut n, 3, output.as_bytes());
    bytes(&mut n, 4, op.as_bytes());
    for (name, values) in ints {
        let mut a = Vec::new();
        bytes(&mut a, 1, name.as_bytes());
        for v in *values {
            int(&mut a, 8, *v as u64);
        }
        int(&mut a, 20, 7); // AttributeType INTS
        bytes(&mut n, 5, &a);
    }
    if let Some((name, v)) = one {
        bytes(&mut n, 5, &int_attr(name, v));
    }
    n
}

/// An `AttributeProto` of one `int`.
fn int_attr(name: &str, v: i64) -> Vec<u8> {
    let mut a = Vec::new();
    bytes(&mut a, 1, name.as_bytes());
    int(&mut a, 3, v as u64);
    int(&mut a, 20, 2); // AttributeType INT
    a
}

/// An `int64` `TensorProto` (an operator's axes), its data raw.
fn int64s(name: &str, data: &[i64]) -> Vec<u8> {
    let mut t = Vec::new();
    int(&mut t, 1, data.len() as u64);
    int(&mut t, 2, 7); // INT64
    bytes(&mut t, 8, name.as_bytes());
    let raw: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
    bytes(&mut t, 9, &raw);
    t
}

/// A float `TensorProto` with its data as raw little-endian bytes.
fn tensor(name: &str, dims: &[usize], data: &[f32]) -> Vec<u8> {
    debug_assert_eq!(dims.iter().product::<usize>(), data.len());
    let mut t = Vec::new();
    for d in dims {
        int(&mut t, 1, *d as u64);
    }
    int(&mut t, 2, 1); // FLOAT
    bytes(&mut t, 8, name.as_bytes());
    let raw: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
    bytes(&mut t, 9, &raw);
    t
}

/// A float tensor's `ValueInfoProto`; `None` is the batch dimension.
fn value_info(name: &str, dims: &[Option<usize>]) -> Vec<u8> {
    let mut shape = Vec::new();
    for d in dims {
        let mut dim = Vec::new();
        match d {
            Some(v) => int(&mut dim, 1, *v as u64),
            None => bytes(&mut dim, 2, b"batch"),
        }
        bytes(&mut shape, 1, &dim);
    }
    let mut tensor_type = Vec::new();
    int(&mut tensor_type, 1, 1); // FLOAT
    bytes(&mut tensor_type, 2, &shape);
    let mut ty = Vec::new();
    bytes(&mut ty, 1, &tensor_type);
    let mut v = Vec::new();
    bytes(&mut v, 1, name.as_bytes());
    bytes(&mut v, 2, &ty);
    v
}
