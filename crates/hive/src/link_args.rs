//! How a host's link is secured and checked: the options `hive train
//! --listen` and `hive worker` share.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;

/// How a host's link is secured: `hive train --listen` and `hive worker`.
#[derive(Args, Debug, Default)]
pub struct LinkArgs {
    /// Mutual TLS for quic/ and tls/ endpoints: a directory with `ca.pem`, `cert.pem`
    /// and `key.pem` (this host's, from `hive certs`).
    #[arg(long, value_name = "DIR")]
    pub tls: Option<PathBuf>,
    /// A Zenoh configuration file (JSON5) laid over rotorhive's: its keys
    /// win (access control, other TLS settings, buffer sizes).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// Listen on a non-loopback address over plain TCP: anyone who reaches
    /// the port can then read the weights and feed the run. Only on a
    /// network you trust.
    #[arg(long)]
    pub insecure: bool,
}

impl LinkArgs {
    /// The link's options (no access control: for checks).
    pub fn options(&self) -> rotorhive_link::LinkOptions {
        rotorhive_link::LinkOptions {
            tls: self.tls.clone(),
            zenoh_config: self.zenoh_config.clone(),
            ..Default::default()
        }
    }

    /// The head's link options: with TLS, only its `workers` workers'
    /// certificates (`hive certs`'s names) may take part.
    pub fn head_options(&self, workers: usize) -> rotorhive_link::LinkOptions {
        rotorhive_link::LinkOptions::for_head(self.tls.clone(), self.zenoh_config.clone(), workers)
    }

    /// A worker's link options: with TLS, only the head's certificate may
    /// take part.
    pub fn worker_options(&self) -> rotorhive_link::LinkOptions {
        rotorhive_link::LinkOptions::for_worker(self.tls.clone(), self.zenoh_config.clone())
    }

    /// Checks an endpoint and its certificates before anything starts.
    pub fn check(&self, ep: &str) -> Result<()> {
        Ok(rotorhive_link::check_options(ep, &self.options())?)
    }

    /// Refuses to listen unencrypted beyond this machine without `--insecure`.
    pub fn check_listen(&self, ep: &str) -> Result<()> {
        self.check(ep)?;
        if !rotorhive_link::is_tls(ep)
            && !rotorhive_link::is_loopback(ep)
            && !self.insecure
            && self.zenoh_config.is_none()
        {
            bail!(
                "--listen {ep}: plain TCP beyond this machine lets anyone who reaches the port read the weights and feed the run; \
                 use quic/ with --tls DIR (see `hive certs`), or add --insecure on a network you trust"
            );
        }
        Ok(())
    }
}
