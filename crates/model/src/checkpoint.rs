//! Checkpoints: safetensors files whose header describes the network
//! (layout, observation, shapes, memory), written with sorted keys and read
//! with every difference named.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor, Var};

use crate::{Layers, ModelError, Result, Shapes};

/// The checkpoint layout this build writes and reads: the tensors' names
/// and shapes, conv2's weights as (out, kh, kw, in) and fc1's pooled
/// features channels-last. A change of any of them changes it.
pub const CHECKPOINT_LAYOUT: &str = "rotorhive-qnet/1";

/// What a checkpoint's safetensors header says of a feedforward network
/// for `shapes`: `layout` ([`CHECKPOINT_LAYOUT`]), `observation`, `frames`,
/// `frame_stride`, `obs_len`, `scalars`, `actions` and `memory` (`none`).
pub fn checkpoint_metadata(shapes: Shapes) -> HashMap<String, String> {
    network_metadata(shapes, Layers::DEFAULT, None)
}

/// The name of a network's memory in a checkpoint's header: `none`, or
/// `gru:WIDTH`.
pub fn memory_name(width: Option<usize>) -> String {
    width.map_or_else(|| "none".to_string(), |w| format!("gru:{w}"))
}

/// [`checkpoint_metadata`] of a network of widths `layers` (named in the
/// entry `layers` unless they are the default, so that a checkpoint of the
/// design's network has the bytes of earlier builds) with a GRU of `width`
/// units (none: the feedforward one).
pub(crate) fn network_metadata(
    shapes: Shapes,
    layers: Layers,
    width: Option<usize>,
) -> HashMap<String, String> {
    let goal = if shapes.goal() {
        ", then the goal's bearing (rad), distance and lateral offset (10 m)"
    } else {
        ""
    };
    let map = if shapes.map > 0 {
        format!(", then {} floats of the camera's map", shapes.map)
    } else {
        String::new()
    };
    let tracks = if shapes.tracks > 0 {
        format!(", then {} floats of the seen movers", shapes.tracks)
    } else {
        String::new()
    };
    let mut meta = HashMap::from([
        ("layout".to_string(), CHECKPOINT_LAYOUT.to_string()),
        (
            "observation".to_string(),
            format!(
                "depth {}x{}x{} in [0, 1] (oldest frame first, {} action period(s) \
                 apart), then velocity 3 (m/s, body frame){goal}{map}{tracks}",
                shapes.frames, shapes.depth[0], shapes.depth[1], shapes.stride
            ),
        ),
        ("frames".to_string(), shapes.frames.to_string()),
        ("frame_stride".to_string(), shapes.stride.to_string()),
        ("obs_len".to_string(), shapes.obs_len().to_string()),
        ("scalars".to_string(), shapes.scalars.to_string()),
        ("actions".to_string(), shapes.actions.to_string()),
        ("memory".to_string(), memory_name(width)),
    ]);
    if layers != Layers::DEFAULT {
        meta.insert("layers".to_string(), layers.name());
    }
    // Named only for frames other than the paper's 32 × 32, so that a
    // checkpoint of those has the bytes of earlier builds.
    if shapes.depth != Shapes::PAPER.depth {
        meta.insert("depth".to_string(), depth_name(shapes.depth));
    }
    // Named only with a map, so that a checkpoint without one has the
    // bytes of earlier builds.
    if shapes.map > 0 {
        meta.insert("map".to_string(), shapes.map.to_string());
    }
    if shapes.tracks > 0 {
        meta.insert("tracks".to_string(), shapes.tracks.to_string());
    }
    meta
}

/// A checkpoint's header entries (none in a file of an early build), and
/// how to name a fault of the file.
fn header_of(path: &Path) -> Result<(HashMap<String, String>, impl Fn(String) -> ModelError)> {
    let file = path.display().to_string();
    let bad = move |message: String| ModelError::Checkpoint { file: file.clone(), message };
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)
        .map_err(|e| bad(format!("not a valid safetensors file: {e}")))?;
    Ok((header.metadata().clone().unwrap_or_default(), bad))
}

/// The shapes a checkpoint was written for, from its header (`frames`,
/// `frame_stride`, `scalars` and `actions`; an entry missing in a checkpoint of an earlier
/// build is the paper's), checked to be ones a task has.
pub fn checkpoint_shapes(path: &Path) -> Result<Shapes> {
    let (meta, bad) = header_of(path)?;
    let field = |k: &str, default: usize| -> Result<usize> {
        meta.get(k).map_or(Ok(default), |v| {
            v.parse().map_err(|_| bad(format!("header entry `{k}` is {v:?}, not a count")))
        })
    };
    let depth = match meta.get("depth") {
        None => Shapes::PAPER.depth,
        Some(v) => parse_depth(v)
            .ok_or_else(|| bad(format!("header entry `depth` is {v:?}, not ROWSxCOLS")))?,
    };
    let shapes = Shapes {
        frames: field("frames", Shapes::PAPER.frames)?,
        stride: field("frame_stride", Shapes::PAPER.stride)?,
        scalars: field("scalars", Shapes::PAPER.scalars)?,
        actions: field("actions", Shapes::PAPER.actions)?,
        map: field("map", 0)?,
        tracks: field("tracks", 0)?,
        depth,
    };
    shapes.check().map_err(|m| bad(format!("header claims {m}")))
}

/// A depth frame's size as a header entry's value, `ROWSxCOLS` (`32x32`).
pub fn depth_name([rows, cols]: [usize; 2]) -> String {
    format!("{rows}x{cols}")
}

/// A depth frame's size from [`depth_name`]'s form.
fn parse_depth(v: &str) -> Option<[usize; 2]> {
    let (r, c) = v.split_once('x')?;
    Some([r.parse().ok()?, c.parse().ok()?])
}

/// Rewrites a safetensors file's JSON header with its keys sorted, so that
/// the same weights give the same bytes (the crate writes the metadata map
/// in `HashMap` order, which differs from process to process; deterministic
/// runs are compared byte for byte). The header keeps its length: the same
/// entries, written compactly by the same serializer.
fn sort_header(bytes: &mut [u8]) {
    let Some(len) =
        bytes.get(..8).map(|b| u64::from_le_bytes(b.try_into().expect("eight bytes")) as usize)
    else {
        return;
    };
    let Some(header) = bytes.get(8..8 + len) else {
        return;
    };
    let Ok(value) = serde_json::from_slice::<serde_json::Value>(header) else {
        return;
    };
    let Ok(sorted) = serde_json::to_vec(&value) else {
        return;
    };
    let text = String::from_utf8_lossy(header);
    if sorted.len() == text.trim_end().len() {
        bytes[8..8 + sorted.len()].copy_from_slice(&sorted);
    }
}

/// Refuses a checkpoint whose header describes another network, naming
/// each difference; a header without these entries (a checkpoint of an
/// earlier build) is left to the name and shape checks.
fn check_layout(bytes: &[u8], file: &str, ours: &HashMap<String, String>) -> Result<()> {
    let Ok((_, header)) = safetensors::SafeTensors::read_metadata(bytes) else {
        return Ok(());
    };
    let Some(theirs) = header.metadata() else {
        return Ok(());
    };
    // A checkpoint of a build before memory is a feedforward network's, one
    // without `layers` the design's widths.
    // One without `map` (or `tracks`) has none.
    // One without `depth` reads the paper's 32 × 32.
    let (none, widths, no_map) = (memory_name(None), Layers::DEFAULT.name(), "0".to_string());
    let paper = depth_name(Shapes::PAPER.depth);
    let default = |k: &str| match k {
        "memory" => Some(&none),
        "layers" => Some(&widths),
        "map" | "tracks" => Some(&no_map),
        "depth" => Some(&paper),
        _ => None,
    };
    let keys = [
        "layout",
        "obs_len",
        "frames",
        "frame_stride",
        "scalars",
        "actions",
        "memory",
        "layers",
        "map",
        "tracks",
        "depth",
    ];
    let diffs: Vec<String> = keys
        .iter()
        .filter_map(|k| {
            let ours = ours.get(*k).or(default(k))?;
            let v = theirs.get(*k).or(default(k))?;
            (v != ours).then(|| format!("{k} {v} (this network: {ours})"))
        })
        .collect();
    if diffs.is_empty() {
        Ok(())
    } else {
        Err(ModelError::Checkpoint {
            file: file.into(),
            message: format!("written for another network: {}", diffs.join(", ")),
        })
    }
}

/// The memory a checkpoint's network has, from its header: `None` for a
/// feedforward one (or a checkpoint of a build before memory), `Some(width)`
/// for a GRU's.
pub fn checkpoint_memory(path: &Path) -> Result<Option<usize>> {
    let (meta, bad) = header_of(path)?;
    match meta.get("memory").map(String::as_str) {
        None | Some("none") => Ok(None),
        Some(m) => m
            .strip_prefix("gru:")
            .and_then(|w| w.parse().ok())
            .filter(|w| (1..=crate::MAX_WIDTH).contains(w))
            .map(Some)
            .ok_or_else(|| bad(format!("header entry `memory` is {m:?}, not none or gru:WIDTH"))),
    }
}

/// A checkpoint's header entry `key` (`None` where it has none).
pub fn checkpoint_entry(path: &Path, key: &str) -> Result<Option<String>> {
    Ok(header_of(path)?.0.remove(key))
}

/// The widths of a checkpoint's network, from its header's `layers` (the
/// design's where it has none).
pub fn checkpoint_layers(path: &Path) -> Result<Layers> {
    let (meta, bad) = header_of(path)?;
    match meta.get("layers") {
        None => Ok(Layers::DEFAULT),
        Some(l) => Layers::parse(l).map_err(|e| bad(format!("header entry `layers`: {e}"))),
    }
}

/// Writes `named` tensors (moved to the CPU) with `meta` in the header,
/// keys sorted, atomically.
pub(crate) fn write(
    path: &Path,
    named: HashMap<String, Tensor>,
    meta: HashMap<String, String>,
) -> Result<()> {
    let cpu: Vec<(String, Tensor)> = named
        .into_iter()
        .map(|(k, t)| Ok((k, t.to_device(&Device::Cpu)?.contiguous()?)))
        .collect::<Result<_>>()?;
    let bad =
        |message: String| ModelError::Checkpoint { file: path.display().to_string(), message };
    let mut bytes =
        safetensors::serialize(cpu, Some(meta)).map_err(|e| bad(format!("cannot write: {e}")))?;
    sort_header(&mut bytes);
    rotorhive_msg::durable::atomic_write(
        path,
        |tmp| std::fs::write(tmp, &bytes).map_err(|e| bad(format!("cannot write: {e}"))),
        |e| bad(format!("cannot write: {e}")),
    )
}

/// The tensors of a checkpoint on `device`, refused when its header
/// describes another network than `ours` says.
pub(crate) fn read(
    path: &Path,
    device: &Device,
    ours: &HashMap<String, String>,
) -> Result<HashMap<String, Tensor>> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| ModelError::Checkpoint {
        file: file.clone(),
        message: format!("cannot read: {e}"),
    })?;
    check_layout(&bytes, &file, ours)?;
    candle_core::safetensors::load_buffer(&bytes, device).map_err(|e| ModelError::Checkpoint {
        file,
        message: format!("not a valid safetensors file: {e}"),
    })
}

/// Sets `vars` (of `specs`' names and shapes, in order) from `tensors`,
/// checking every name, shape, dtype and value: a tensor the network does
/// not have, one of integers, or one holding a NaN or an infinity is
/// refused by name, so no command flies or exports weights that cannot
/// compute a Q-value.
pub(crate) fn load_vars(
    specs: &[(&'static str, Vec<usize>)],
    vars: &[Var],
    tensors: &HashMap<String, Tensor>,
    file: &str,
    device: &Device,
) -> Result<()> {
    let bad = |message: String| ModelError::Checkpoint { file: file.into(), message };
    let mut extra: Vec<&str> =
        tensors.keys().map(String::as_str).filter(|k| !specs.iter().any(|(n, _)| n == k)).collect();
    if !extra.is_empty() {
        extra.sort_unstable();
        return Err(bad(format!(
            "tensor `{}` is not part of this network ({} such)",
            extra[0],
            extra.len()
        )));
    }
    for ((name, shape), v) in specs.iter().zip(vars) {
        let t = tensors.get(*name).ok_or_else(|| bad(format!("tensor `{name}` is missing")))?;
        if t.dims() != *shape {
            return Err(bad(format!(
                "tensor `{name}` has shape {:?}, the network needs {:?}",
                t.dims(),
                shape
            )));
        }
        let values = finite_floats(t, name, &bad)?;
        v.set(&Tensor::from_vec(values, shape.as_slice(), device)?)?;
    }
    Ok(())
}

/// The values of a checkpoint's tensor `name` as f32, refused (through
/// `bad`) when it holds integers or any value that is not finite.
fn finite_floats(t: &Tensor, name: &str, bad: &dyn Fn(String) -> ModelError) -> Result<Vec<f32>> {
    if !t.dtype().is_float() {
        return Err(bad(format!("tensor `{name}` holds {:?}, not floats", t.dtype())));
    }
    let values =
        t.to_device(&Device::Cpu)?.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
    let broken = values.iter().filter(|x| !x.is_finite()).count();
    if broken > 0 {
        return Err(bad(format!(
            "tensor `{name}` holds {broken} values of {} that are not finite (NaN or infinity)",
            values.len()
        )));
    }
    Ok(values)
}

/// A learner's whole state as read back by [`read_state`]: both networks'
/// tensors by name, Adam's moments (one vector per parameter, in order) and
/// step, and the learner's update count.
pub(crate) struct LearnerState {
    pub online: HashMap<String, Tensor>,
    pub target: HashMap<String, Tensor>,
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
    pub t: u64,
    pub updates: u64,
}

/// Saves a learner's whole state (the networks `online` and `target` of
/// `specs`' names and shapes, Adam's first and second moments `m`, `v` and
/// step `t`, the update count) as one safetensors file, atomically.
pub(crate) fn save_state(
    path: &Path,
    specs: &[(&'static str, Vec<usize>)],
    (online, target): (&[Var], &[Var]),
    (m, v, t): (&[Vec<f32>], &[Vec<f32>], u64),
    updates: u64,
) -> Result<()> {
    let dev = Device::Cpu;
    let mut map: HashMap<String, Tensor> = HashMap::new();
    let moments = m.iter().zip(v);
    for ((name, shape), ((o, t), (m, v))) in
        specs.iter().zip(online.iter().zip(target).zip(moments))
    {
        map.insert(format!("online.{name}"), o.as_tensor().to_device(&dev)?);
        map.insert(format!("target.{name}"), t.as_tensor().to_device(&dev)?);
        map.insert(format!("adam_m.{name}"), Tensor::from_slice(m, shape.as_slice(), &dev)?);
        map.insert(format!("adam_v.{name}"), Tensor::from_slice(v, shape.as_slice(), &dev)?);
    }
    map.insert("adam_t".into(), Tensor::new(&[t as i64], &dev)?);
    map.insert("updates".into(), Tensor::new(&[updates as i64], &dev)?);
    let bad = |e: std::io::Error| ModelError::Checkpoint {
        file: path.display().to_string(),
        message: format!("cannot write: {e}"),
    };
    rotorhive_msg::durable::atomic_write(
        path,
        |tmp| Ok(candle_core::safetensors::save(&map, tmp)?),
        bad,
    )
}

/// Reads a state written by [`save_state`] for a network of `specs`,
/// checking the counters and every moment's name and shape (the networks'
/// tensors are checked as they are loaded).
pub(crate) fn read_state(
    path: &Path,
    specs: &[(&'static str, Vec<usize>)],
) -> Result<LearnerState> {
    let file = path.display().to_string();
    let bad = |message: String| ModelError::Checkpoint { file: file.clone(), message };
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let map = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu)
        .map_err(|e| bad(format!("not a valid safetensors file: {e}")))?;
    let sub = |prefix: &str| -> HashMap<String, Tensor> {
        map.iter()
            .filter_map(|(k, v)| k.strip_prefix(prefix).map(|n| (n.to_string(), v.clone())))
            .collect()
    };
    let counter = |name: &str| -> Result<u64> {
        let t = map.get(name).ok_or_else(|| bad(format!("tensor `{name}` is missing")))?;
        let v = t.to_dtype(DType::I64)?.flatten_all()?.to_vec1::<i64>()?;
        match v.as_slice() {
            [x] if *x >= 0 => Ok(*x as u64),
            _ => Err(bad(format!("tensor `{name}` is not one non-negative count"))),
        }
    };
    let (t, updates) = (counter("adam_t")?, counter("updates")?);
    let mut moments = Vec::new();
    for prefix in ["adam_m.", "adam_v."] {
        let part = sub(prefix);
        let mut vecs = Vec::new();
        for (name, shape) in specs {
            let x = part
                .get(*name)
                .ok_or_else(|| bad(format!("tensor `{prefix}{name}` is missing")))?;
            if x.dims() != shape.as_slice() {
                return Err(bad(format!(
                    "tensor `{prefix}{name}` has shape {:?}, the network needs {shape:?}",
                    x.dims()
                )));
            }
            vecs.push(finite_floats(x, &format!("{prefix}{name}"), &bad)?);
        }
        moments.push(vecs);
    }
    let v = moments.pop().unwrap_or_default();
    let m = moments.pop().unwrap_or_default();
    Ok(LearnerState { online: sub("online."), target: sub("target."), m, v, t, updates })
}

#[cfg(test)]
mod tests;
