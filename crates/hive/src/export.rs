//! `hive export`: a checkpoint as an ONNX model (`rotorhive_model`'s
//! `QNet::to_onnx`, or `RecurrentQNet::to_onnx` for one with memory).

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use rotorhive_model::{Device, QNet, RecurrentQNet};

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
    let shapes = rotorhive_model::checkpoint_shapes(&a.checkpoint)?;
    let source = [("source", a.checkpoint.display().to_string())];
    let ins = format!("depth (B, {}, 32, 32) and velocity (B, {})", shapes.frames, shapes.scalars);
    // A checkpoint whose header names a memory exports its one step, the
    // state in and out.
    if let Some(width) = rotorhive_model::checkpoint_memory(&a.checkpoint)? {
        let net = RecurrentQNet::new(shapes, width, 0, &Device::Cpu)?;
        net.load(&a.checkpoint)?;
        net.to_onnx(&a.out, &source)?;
        println!(
            "{}: inputs {ins} and state (B, {width}), outputs q (B, {}) and next_state (B, {width})",
            a.out.display(),
            shapes.actions
        );
        return Ok(());
    }
    let net = QNet::with_shapes(shapes, 0, &Device::Cpu)?;
    net.load(&a.checkpoint)?;
    net.to_onnx(&a.out, &source)?;
    println!("{}: inputs {ins}, output q (B, {})", a.out.display(), shapes.actions);
    Ok(())
}
