//! `hive export`: a checkpoint as an ONNX model (`rotorhive_model`'s
//! `QNet::to_onnx`).

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use rotorhive_model::{Device, QNet};

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
    let net = QNet::with_shapes(shapes, 0, &Device::Cpu)?;
    net.load(&a.checkpoint)?;
    net.to_onnx(&a.out, &[("source", a.checkpoint.display().to_string())])?;
    println!(
        "{}: inputs depth (B, {}, 32, 32) and velocity (B, {}), output q (B, {})",
        a.out.display(),
        shapes.frames,
        shapes.scalars,
        shapes.actions
    );
    Ok(())
}
