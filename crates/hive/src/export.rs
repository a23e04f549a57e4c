//! `hive export`: a checkpoint as an ONNX model (`rotorhive_model`'s
//! `PolicyNet::to_onnx`: one with memory as a single step with its state).

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use rotorhive_model::PolicyNet;

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Weights (safetensors) written by `hive train`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// The ONNX file to write (.onnx).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: ExportArgs) -> Result<()> {
    if a.out.extension().and_then(|e| e.to_str()) != Some("onnx") {
        bail!("--out {}: the file must end in .onnx", a.out.display());
    }
    // Either network, as the checkpoint's header says (shapes, memory): a
    // recurrent one exports its one step, the state in and out.
    let net = PolicyNet::load(&a.checkpoint)?;
    // The camera it was trained with goes into the model's metadata too.
    let camera = rotorhive_roles::config::camera::checkpoint_camera(&a.checkpoint)?;
    let meta = [
        ("source", a.checkpoint.display().to_string()),
        ("camera", rotorhive_roles::config::camera::camera_name(&camera)),
    ];
    net.to_onnx(&a.out, &meta)?;
    let shapes = net.shapes();
    let mut ins = format!(
        "depth (B, {}, {}, {}) and velocity (B, {})",
        shapes.frames,
        shapes.depth[0],
        shapes.depth[1],
        shapes.scalars - shapes.map
    );
    if shapes.map > 0 {
        ins.push_str(&format!(" and map (B, {})", shapes.map));
    }
    let (out, actions) = (a.out.display(), shapes.actions);
    match net.memory() {
        Some(w) => println!(
            "{out}: inputs {ins} and state (B, {w}), outputs q (B, {actions}) and next_state (B, {w})"
        ),
        None => println!("{out}: inputs {ins}, output q (B, {actions})"),
    }
    Ok(())
}
