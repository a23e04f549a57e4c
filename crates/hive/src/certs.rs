//! `hive certs`: what a run across hosts over mutual TLS needs (see
//! `rotorhive_link::certs`).

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;

/// `hive certs` arguments.
#[derive(Args, Debug)]
pub struct CertsArgs {
    /// Directory to write: `ca.pem`, `ca.key`, and `head/`, `worker-1/`, ...
    #[arg(long, default_value = "certs")]
    pub out: PathBuf,
    /// Worker hosts to make certificates for.
    #[arg(long, default_value_t = 1)]
    pub workers: usize,
    /// Names and addresses the workers reach the head by (its certificate
    /// must name the one in their `--connect`); repeatable. Loopback names
    /// and this machine's name are always added.
    #[arg(long = "head-name", value_name = "NAME_OR_IP")]
    pub head_names: Vec<String>,
    /// Overwrite an existing CA in OUT.
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: CertsArgs) -> Result<()> {
    if a.workers == 0 || a.workers > 1000 {
        bail!("--workers must be from 1 to 1000, got {}", a.workers);
    }
    if a.out.join("ca.pem").exists() && !a.force {
        bail!(
            "{} already holds a CA: a new one would lock out every host that has the old one (--force to replace it)",
            a.out.display()
        );
    }
    let mut names = vec![crate::supervisor::host_name()];
    names.extend(a.head_names.iter().cloned());
    let dirs = rotorhive_link::certs::make(&a.out, a.workers, &names)?;
    println!(
        "wrote a CA and {} host certificates under {}: give each host its directory (head/, worker-1/, ...) as --tls; keep ca.key to yourself",
        dirs.len(),
        a.out.display()
    );
    Ok(())
}
