//! How a link opens its Zenoh session: the endpoint's form, mutual TLS
//! from a directory of `hive certs`, the access-control rules, a user's
//! Zenoh config laid over ours, and the options both ends are given.

use std::path::{Path, PathBuf};

use zenoh::Wait;

use crate::certs;
use crate::error::{LinkError, Result, zerr};
use crate::shared::{MAX_EPISODES_BYTES, MAX_MESSAGE_BYTES, MAX_TELEMETRY_BYTES};

/// Checks that `ep` is `tcp/HOST:PORT` or `tls/HOST:PORT`; its host.
pub fn check_endpoint(ep: &str) -> Result<&str> {
    let bad = || LinkError::BadEndpoint(ep.to_string());
    let rest = ep
        .strip_prefix("tcp/")
        .or_else(|| ep.strip_prefix("tls/"))
        .or_else(|| ep.strip_prefix("quic/"))
        .ok_or_else(bad)?;
    let (host, port) = rest.rsplit_once(':').ok_or_else(bad)?;
    if host.is_empty() || port.parse::<u16>().is_err() {
        return Err(bad());
    }
    Ok(host)
}

/// Whether `ep` is encrypted and authenticated (mutual TLS, over TCP or
/// QUIC).
pub fn is_tls(ep: &str) -> bool {
    ep.starts_with("tls/") || ep.starts_with("quic/")
}

/// Whether `ep` can be reached from this machine only.
pub fn is_loopback(ep: &str) -> bool {
    match check_endpoint(ep) {
        Ok(host) => {
            let host = host.trim_start_matches('[').trim_end_matches(']');
            host == "localhost" || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
        }
        Err(_) => false,
    }
}

/// How a host's link is secured and configured.
#[derive(Debug, Clone, Default)]
pub struct LinkOptions {
    /// A directory with `ca.pem`, `cert.pem` and `key.pem` (as `hive certs`
    /// writes them): mutual TLS on `tls/` endpoints, each side checking the
    /// other's certificate against the run's CA.
    pub tls: Option<PathBuf>,
    /// A Zenoh configuration file (JSON5) whose keys win over rotorhive's.
    pub zenoh_config: Option<PathBuf>,
    /// With `tls`: the certificate common names of the hosts this one may
    /// talk to (the head: its workers'; a worker: the head's). Zenoh's
    /// access control then denies every message on the run's keys to and
    /// from any other peer, even one holding a certificate of the run's CA.
    /// Empty: no access control.
    pub peers: Vec<String>,
    /// The head: `peers[i]` is worker slot `i + 1`'s certificate, which
    /// may join as that slot only and put on that slot's keys only.
    pub peers_are_slots: bool,
    /// A worker: the slot its certificate holds (`hive certs` writes it as
    /// `slot` in the worker's directory), asked for at the join.
    pub slot: Option<u32>,
}

impl LinkOptions {
    /// The head's options: `tls` and `zenoh_config`, talking to the
    /// certificates of `hive certs`'s workers 1..=`workers`.
    pub fn for_head(tls: Option<PathBuf>, zenoh_config: Option<PathBuf>, workers: usize) -> Self {
        Self {
            tls,
            zenoh_config,
            peers: (1..=workers).map(|i| certs::common_name(&format!("worker-{i}"))).collect(),
            peers_are_slots: true,
            slot: None,
        }
    }

    /// A worker's options: `tls` and `zenoh_config`, talking to the head's
    /// certificate only.
    pub fn for_worker(tls: Option<PathBuf>, zenoh_config: Option<PathBuf>) -> Self {
        let slot = tls.as_deref().and_then(certs::slot_of);
        Self {
            tls,
            zenoh_config,
            peers: vec![certs::common_name("head")],
            peers_are_slots: false,
            slot,
        }
    }
}

/// The files of a TLS directory, checked to exist.
pub fn tls_files(dir: &Path) -> Result<[PathBuf; 3]> {
    let files = ["ca.pem", "cert.pem", "key.pem"].map(|f| dir.join(f));
    for f in &files {
        if !f.is_file() {
            return Err(LinkError::Tls(format!(
                "--tls {}: {} is missing (make the run's certificates with `hive certs`)",
                dir.display(),
                f.display()
            )));
        }
    }
    Ok(files)
}

/// Checks an endpoint with the options it is opened with: its form, the
/// `--tls` directory's files, and a certificate for an encrypted endpoint
/// (unless a Zenoh configuration file brings its own).
pub fn check_options(ep: &str, opts: &LinkOptions) -> Result<()> {
    check_endpoint(ep)?;
    match &opts.tls {
        Some(dir) => {
            tls_files(dir)?;
        }
        None if is_tls(ep) && opts.zenoh_config.is_none() => {
            return Err(LinkError::Tls(format!(
                "{ep} needs --tls DIR: the run's CA and this host's certificate and key (made by `hive certs`)"
            )));
        }
        None => {}
    }
    Ok(())
}

/// How long a silent link is given before its session is dropped (ms): a
/// network outage or a stalled head shorter than this loses nothing.
pub const LEASE_MS: u64 = 60_000;

pub(crate) fn set(c: &mut zenoh::Config, k: &str, v: &str) -> Result<()> {
    c.insert_json5(k, v).map_err(|cause| LinkError::Zenoh { what: format!("config {k}"), cause })
}

/// Mutual TLS from a directory of `hive certs`: both ends present their
/// certificate and check the other's against the run's CA.
fn set_tls(c: &mut zenoh::Config, dir: &Path) -> Result<()> {
    let [ca, cert, key] = tls_files(dir)?;
    let q = |p: &Path| format!("{:?}", p.display().to_string());
    set(c, "transport/link/tls/root_ca_certificate", &q(&ca))?;
    for side in ["listen", "connect"] {
        set(c, &format!("transport/link/tls/{side}_private_key"), &q(&key))?;
        set(c, &format!("transport/link/tls/{side}_certificate"), &q(&cert))?;
    }
    set(c, "transport/link/tls/enable_mtls", "true")?;
    set(c, "transport/link/tls/verify_name_on_connect", "true")
}

/// The messages a host's access control admits on the run's keys.
const MESSAGES: &str = r#"["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]"#;

/// Zenoh's access control (JSON5) for a host that talks to the peers whose
/// certificates have the common names `peers`: everything on the run's
/// keys to them; from them, what they may send. With `slots` (the head),
/// `peers[i]` is worker slot `i + 1`: it may subscribe and ask anywhere on
/// the run's keys, but join only as its slot (`rotorhive/join/SLOT`) and
/// put only on its slot's keys (`rotorhive/RUN/host/SLOT/...`). Everything
/// else, and every other certificate, is denied.
fn access_control(peers: &[String], slots: bool) -> String {
    let q = |p: &String| format!("{p:?}");
    let names: Vec<String> = peers.iter().map(q).collect();
    let mut rules = vec![format!(
        r#"{{ id: "out", key_exprs: ["rotorhive/**"], flows: ["egress"], permission: "allow", messages: {MESSAGES} }}"#
    )];
    let mut subjects =
        vec![format!(r#"{{ id: "peers", cert_common_names: [{}] }}"#, names.join(", "))];
    let mut policies = vec![r#"{ rules: ["out", "in"], subjects: ["peers"] }"#.to_string()];
    if slots {
        rules.push(r#"{ id: "in", key_exprs: ["rotorhive/**"], flows: ["ingress"], permission: "allow",
            messages: ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"] }"#
            .into());
        for (i, p) in peers.iter().enumerate() {
            let slot = i + 1;
            rules.push(format!(
                r#"{{ id: "slot-{slot}", flows: ["ingress"], permission: "allow",
                     key_exprs: ["rotorhive/join/{slot}", "rotorhive/*/host/{slot}", "rotorhive/*/host/{slot}/**"],
                     messages: ["put", "delete", "query", "liveliness_token"] }}"#
            ));
            subjects.push(format!(r#"{{ id: "worker-{slot}", cert_common_names: [{}] }}"#, q(p)));
            policies.push(format!(r#"{{ rules: ["slot-{slot}"], subjects: ["worker-{slot}"] }}"#));
        }
    } else {
        rules.push(format!(
            r#"{{ id: "in", key_exprs: ["rotorhive/**"], flows: ["ingress"], permission: "allow", messages: {MESSAGES} }}"#
        ));
    }
    format!(
        r#"{{ enabled: true, default_permission: "deny", rules: [{}], subjects: [{}], policies: [{}] }}"#,
        rules.join(", "),
        subjects.join(", "),
        policies.join(", ")
    )
}

/// Lays the keys of a user's Zenoh configuration file over `c` (the file's
/// keys win; objects merge key by key, anything else replaces).
fn overlay(c: &mut zenoh::Config, path: &Path) -> Result<()> {
    let bad = |message: String| LinkError::ZenohConfig { path: path.to_path_buf(), message };
    // Zenoh's own reader first: it names an unknown key or a bad value.
    zenoh::Config::from_file(path).map_err(|e| bad(e.to_string()))?;
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let value: serde_json::Value = json5::from_str(&text).map_err(|e| bad(e.to_string()))?;
    fn walk(
        c: &mut zenoh::Config,
        at: &str,
        v: &serde_json::Value,
    ) -> std::result::Result<(), String> {
        match v {
            serde_json::Value::Object(m) if !m.is_empty() => {
                for (k, v) in m {
                    walk(c, &if at.is_empty() { k.clone() } else { format!("{at}/{k}") }, v)?;
                }
                Ok(())
            }
            _ => c.insert_json5(at, &v.to_string()).map_err(|e| format!("{at}: {e}")),
        }
    }
    walk(c, "", &value).map_err(bad)
}

/// Opens a peer session that listens on or connects to `endpoint`.
pub(crate) fn open(
    listen: Option<&str>,
    connect: Option<&str>,
    opts: &LinkOptions,
) -> Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    set(&mut c, "mode", r#""peer""#)?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    // A head held busy for a while must not make zenoh close the link and
    // lose what is in flight (the default is 5 s); the head's own stall is
    // bounded by the run's stop.
    set(&mut c, "transport/link/tx/queue/congestion_control/block/wait_before_close", "60000000")?;
    // A link that goes quiet (a network outage, a head held busy) is given
    // LEASE_MS before either end declares the other dead and drops the
    // session with what it holds in flight; TCP carries what waited once
    // the link is back (zenoh's default lease is 10 s; keep-alives go every
    // quarter of it).
    set(&mut c, "transport/link/tx/lease", &LEASE_MS.to_string())?;
    // A transition batch is hundreds of kilobytes: read the link in large
    // chunks (the default is one 64 KiB batch).
    set(&mut c, "transport/link/rx/buffer_size", "4194304")?;
    // Bounded memory: no message above a full batch, and the head's queues
    // of episodes and telemetry bounded in bytes by Zenoh's low-pass filter.
    set(&mut c, "transport/link/rx/max_message_size", &MAX_MESSAGE_BYTES.to_string())?;
    set(
        &mut c,
        "low_pass_filter",
        &format!(
            r#"[{{ messages: ["put"], flows: ["ingress"], key_exprs: ["rotorhive/*/host/*/episodes"], size_limit: {MAX_EPISODES_BYTES} }},
                {{ messages: ["put"], flows: ["ingress"], key_exprs: ["rotorhive/*/host/*/telemetry", "rotorhive/*/end"], size_limit: {MAX_TELEMETRY_BYTES} }}]"#
        ),
    )?;
    if let Some(ep) = listen.or(connect) {
        check_options(ep, opts)?;
    }
    if let Some(dir) = &opts.tls {
        set_tls(&mut c, dir)?;
        if !opts.peers.is_empty() {
            set(&mut c, "access_control", &access_control(&opts.peers, opts.peers_are_slots))?;
        }
    }
    match (listen, connect) {
        (Some(l), _) => {
            set(&mut c, "listen/endpoints", &format!(r#"["{l}"]"#))?;
            set(&mut c, "connect/endpoints", "[]")?;
        }
        (None, Some(k)) => {
            set(&mut c, "listen/endpoints", "[]")?;
            set(&mut c, "connect/endpoints", &format!(r#"["{k}"]"#))?;
        }
        (None, None) => {}
    }
    if let Some(f) = &opts.zenoh_config {
        overlay(&mut c, f)?;
    }
    let what = match (listen, connect) {
        (Some(l), _) => format!("listen on {l}"),
        (None, Some(k)) => format!("connect to {k}"),
        _ => "open".into(),
    };
    zenoh::open(c).wait().map_err(zerr(what))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn access_control_holds_each_worker_to_its_slot() {
        let peers: Vec<String> = (1..=3).map(|i| format!("rotorhive-worker-{i}")).collect();
        for slots in [true, false] {
            let acl = access_control(&peers, slots);
            // Zenoh reads it (it checks the rules' fields and key expressions).
            let mut c = zenoh::Config::default();
            set(&mut c, "access_control", &acl).unwrap();
            let v: serde_json::Value = json5::from_str(&acl).unwrap();
            let rules = v["rules"].as_array().unwrap();
            let of = |id: &str| rules.iter().find(|r| r["id"] == id).cloned();
            if slots {
                // Worker 2 may join and put as slot 2 only; nobody may put anywhere else.
                let two = of("slot-2").unwrap();
                let keys: Vec<&str> = two["key_exprs"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter_map(|k| k.as_str())
                    .collect();
                assert_eq!(
                    keys,
                    ["rotorhive/join/2", "rotorhive/*/host/2", "rotorhive/*/host/2/**"]
                );
                let inbound = of("in").unwrap();
                assert!(!inbound["messages"].as_array().unwrap().iter().any(|m| m == "put"));
                assert_eq!(v["subjects"].as_array().unwrap().len(), 4);
            } else {
                assert!(of("slot-1").is_none());
            }
        }
    }
}
