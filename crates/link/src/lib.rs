//! The link between hosts: the only crate that imports zenoh.
//!
//! iceoryx2 stays the transport inside each host; the link of a host is one
//! more member of its run that carries, over one Zenoh session on TCP (peer
//! mode, explicit endpoints, no multicast, no router):
//! - transition batches worker → head, loss-free: zenoh's
//!   `CongestionControl::Block`, a bounded FIFO on the head, then the head's
//!   bounded iceoryx2 send retried while the replay is full, so back-pressure
//!   reaches the worker's actors end to end;
//! - weights head → worker, newest only (a ring of one), republished on the
//!   worker's shared memory once per host;
//! - telemetry and episodes worker → head (they may drop under load; drops
//!   are counted).
//!
//! Observations, actions and minibatches never leave their host. Headers and
//! payloads cross as raw bytes ([`wire`]); both ends check the layout
//! fingerprint at the join and refuse a mismatch.

pub mod certs;
pub mod check;
pub mod wire;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::service::Service;
use rotorhive_msg::{
    EPISODE_FIELDS, EpisodeHeader, LinkStage, RoleKind, SeqTracker, Telemetry, TransitionHeader,
    WeightsHeader,
};
use rotorhive_transport::{Channel, Hub, TransportError};
use zenoh::Wait;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel};
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::SampleKind;

pub use wire::{Hello, Welcome};

/// Errors of the link, naming the endpoint or the peer.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// An endpoint that is not `tcp/`, `tls/` or `quic/HOST:PORT`.
    #[error(
        "endpoint {0:?}: expected tcp/HOST:PORT, tls/HOST:PORT or quic/HOST:PORT (for example quic/192.168.1.10:7447)"
    )]
    BadEndpoint(String),
    /// A `tls/` endpoint without certificates, or certificates that are not there.
    #[error("{0}")]
    Tls(String),
    /// A Zenoh configuration file that cannot be read.
    #[error("zenoh config {path}: {message}")]
    ZenohConfig {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Zenoh refused to open the session or a declaration.
    #[error("zenoh ({what}): {message}")]
    Zenoh {
        /// What was attempted.
        what: String,
        /// Zenoh's error.
        message: String,
    },
    /// No head answered a worker in time.
    #[error(
        "no head answered at {endpoint} within {secs:.0} s (is `hive train --listen {endpoint}` running there, and the port open?)"
    )]
    NoHead {
        /// The endpoint tried.
        endpoint: String,
        /// Seconds waited.
        secs: f64,
    },
    /// The head refused the worker.
    #[error("the head at {endpoint} refused this worker: {why}")]
    Refused {
        /// The head's endpoint.
        endpoint: String,
        /// Its reason.
        why: String,
    },
    /// Too few workers joined before the timeout.
    #[error(
        "only {joined} of {wanted} worker hosts joined within {secs:.0} s (`cluster.join_timeout_s`)"
    )]
    TooFewWorkers {
        /// Joined.
        joined: usize,
        /// Wanted.
        wanted: usize,
        /// Seconds waited.
        secs: f64,
    },
    /// The head went away without ending the run.
    #[error("lost the head: its session ended without the run's end")]
    LostHead,
    /// Shared memory on this host.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// Stopped by a signal while waiting.
    #[error("stopped while waiting for {0}")]
    Stopped(&'static str),
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, LinkError>;

fn zerr(what: impl Into<String>) -> impl FnOnce(zenoh::Error) -> LinkError {
    let what = what.into();
    move |e| LinkError::Zenoh { what, message: e.to_string() }
}

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
}

impl LinkOptions {
    /// The head's options: `tls` and `zenoh_config`, talking to the
    /// certificates of `hive certs`'s workers 1..=`workers`.
    pub fn for_head(tls: Option<PathBuf>, zenoh_config: Option<PathBuf>, workers: usize) -> Self {
        Self {
            tls,
            zenoh_config,
            peers: (1..=workers).map(|i| certs::common_name(&format!("worker-{i}"))).collect(),
        }
    }

    /// A worker's options: `tls` and `zenoh_config`, talking to the head's
    /// certificate only.
    pub fn for_worker(tls: Option<PathBuf>, zenoh_config: Option<PathBuf>) -> Self {
        Self { tls, zenoh_config, peers: vec![certs::common_name("head")] }
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

/// The largest message a host accepts: a full transition batch (1,024 ×
/// 8,228 bytes) with room to spare; Zenoh's default is 1 GiB.
pub const MAX_MESSAGE_BYTES: usize = 16 << 20;
/// The largest episodes message (4,096 records) and telemetry sample the
/// head accepts, by Zenoh's low-pass filter, so that its queues of them stay
/// bounded in bytes.
const MAX_EPISODES_BYTES: usize = check::MAX_EPISODES * EPISODE_FIELDS * 4 + 4096;
const MAX_TELEMETRY_BYTES: usize = 4096;

/// The layout this build sends: the message layout and the model's size.
pub fn layout(num_params: usize) -> u64 {
    rotorhive_msg::layout_fingerprint() ^ (num_params as u64).rotate_left(17)
}

fn set(c: &mut zenoh::Config, k: &str, v: &str) -> Result<()> {
    c.insert_json5(k, v)
        .map_err(|e| LinkError::Zenoh { what: format!("config {k}"), message: e.to_string() })
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

/// Zenoh's access control (JSON5) for a host that talks to the peers whose
/// certificates have the common names `peers`: everything on the run's
/// keys (`rotorhive/**`: the join, transitions, episodes, telemetry,
/// weights, the end, liveliness), both ways, with them; nothing with
/// anyone else.
fn access_control(peers: &[String]) -> String {
    let names: Vec<String> = peers.iter().map(|p| format!("{p:?}")).collect();
    format!(
        r#"{{ enabled: true, default_permission: "deny",
             rules: [{{ id: "run", key_exprs: ["rotorhive/**"], flows: ["ingress", "egress"], permission: "allow",
                        messages: ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                                   "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"] }}],
             subjects: [{{ id: "peers", cert_common_names: [{}] }}],
             policies: [{{ rules: ["run"], subjects: ["peers"] }}] }}"#,
        names.join(", ")
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
fn open(listen: Option<&str>, connect: Option<&str>, opts: &LinkOptions) -> Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    set(&mut c, "mode", r#""peer""#)?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    // A head held busy for a while must not make zenoh close the link and
    // lose what is in flight (the default is 5 s); the head's own stall is
    // bounded by the run's stop.
    set(&mut c, "transport/link/tx/queue/congestion_control/block/wait_before_close", "60000000")?;
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
            set(&mut c, "access_control", &access_control(&opts.peers))?;
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

fn key(run: &str, what: &str) -> String {
    format!("rotorhive/{run}/{what}")
}

/// The key a worker in `slot` puts `what` on: the head knows the sender by
/// it (with mutual TLS and an access-control rule, only that host may).
fn host_key(run: &str, slot: u32, what: &str) -> String {
    format!("rotorhive/{run}/host/{slot}/{what}")
}

/// The key of the join queryable.
const JOIN: &str = "rotorhive/join";

/// A worker host of the run, as the head sees it.
#[derive(Debug, Clone)]
pub struct Host {
    /// Host name.
    pub name: String,
    /// Its place (1 = first worker).
    pub slot: u32,
    /// Environments.
    pub envs: u32,
    /// Agents per environment.
    pub agents: u32,
    /// Its first environment's index in the run.
    pub env_offset: u32,
    /// The join token it first joined with: it comes back only with it.
    pub(crate) token: String,
}

/// Whether a join token matches the one a host first joined with (in time
/// that does not depend on where they differ).
fn same_token(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

/// Counters of the head's link, shared with the supervisor.
#[derive(Debug, Default)]
pub struct HeadStats {
    /// Transition batches brought in.
    pub batches: AtomicU64,
    /// Transitions brought in.
    pub transitions: AtomicU64,
    /// Transition batches lost between hosts (per-actor sequence gaps).
    pub lost_batches: AtomicU64,
    /// Transitions in the lost batches, estimated at the batch size seen.
    pub lost_transitions: AtomicU64,
    /// The same, per environment of the run (index = actor).
    pub lost_by_env: std::sync::Mutex<Vec<u64>>,
    /// Episode or telemetry messages that could not be delivered.
    pub dropped: AtomicU64,
    /// Messages that failed a check ([`check`]) and were dropped, per
    /// slot (0: keys that name no host of the run).
    pub rejected: std::sync::Mutex<Vec<u64>>,
}

impl HeadStats {
    /// Counts a dropped message from `slot`; logs the first few of each
    /// host and then every thousandth.
    fn reject(&self, slot: u32, what: &str, why: &check::Reject) {
        let Ok(mut r) = self.rejected.lock() else {
            return;
        };
        if r.len() <= slot as usize {
            r.resize(slot as usize + 1, 0);
        }
        r[slot as usize] += 1;
        let n = r[slot as usize];
        if n <= 5 || n % 1000 == 0 {
            let from =
                if slot == 0 { "an unknown sender".to_string() } else { format!("worker {slot}") };
            tracing::warn!("dropped {what} from {from}: {why} ({n} dropped from it so far)");
        }
    }

    /// Messages dropped from `slot`.
    pub fn rejected_from(&self, slot: u32) -> u64 {
        self.rejected.lock().ok().and_then(|r| r.get(slot as usize).copied()).unwrap_or(0)
    }
}

/// The head's end of the link: listens, admits workers, then bridges.
pub struct Head {
    session: zenoh::Session,
    run: String,
    layout: u64,
    queryable: zenoh::query::Queryable<FifoChannelHandler<Query>>,
    _token: zenoh::liveliness::LivelinessToken,
    hosts: Vec<Host>,
    pending: Vec<(Query, Hello)>,
    default_agents: u32,
    subs: HeadSubscribers,
}

type Fifo = zenoh::pubsub::Subscriber<FifoChannelHandler<zenoh::sample::Sample>>;

/// The head's subscribers, declared before any worker is admitted, so that
/// a worker's first batch already has somewhere to go.
struct HeadSubscribers {
    transitions: Fifo,
    episodes: Fifo,
    telemetry:
        zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<zenoh::sample::Sample>>,
}

impl Head {
    /// Listens on `endpoint` for the workers of run `run`.
    pub fn listen(endpoint: &str, run: &str, layout: u64, opts: &LinkOptions) -> Result<Self> {
        let session = open(Some(endpoint), None, opts)?;
        let queryable = session
            .declare_queryable(JOIN)
            .with(FifoChannel::new(64))
            .wait()
            .map_err(zerr("declare the join queryable"))?;
        let token = session
            .liveliness()
            .declare_token(key(run, "head"))
            .wait()
            .map_err(zerr("declare the head's liveliness"))?;
        let decl = |what: &str| zerr(format!("declare {what}"));
        let subs = HeadSubscribers {
            transitions: session
                .declare_subscriber(key(run, "host/*/transitions"))
                .with(FifoChannel::new(4))
                .wait()
                .map_err(decl("the transitions subscriber"))?,
            episodes: session
                .declare_subscriber(key(run, "host/*/episodes"))
                .with(FifoChannel::new(256))
                .wait()
                .map_err(decl("the episodes subscriber"))?,
            telemetry: session
                .declare_subscriber(key(run, "host/*/telemetry"))
                .with(RingChannel::new(256))
                .wait()
                .map_err(decl("the telemetry subscriber"))?,
        };
        Ok(Self {
            subs,
            session,
            run: run.to_string(),
            layout,
            queryable,
            _token: token,
            hosts: Vec::new(),
            pending: Vec::new(),
            default_agents: 1,
        })
    }

    /// Waits for `wanted` workers (at most `timeout`) and places their
    /// environments after the head's `head_envs`, in order of joining. They
    /// wait for their answer until [`Head::admit`].
    /// A worker that asks for 0 agents per environment gets `default_agents`.
    pub fn gather(
        &mut self,
        wanted: usize,
        head_envs: usize,
        default_agents: usize,
        timeout: Duration,
        stop: impl Fn() -> bool,
    ) -> Result<Vec<Host>> {
        self.default_agents = default_agents as u32;
        let start = Instant::now();
        while self.pending.len() < wanted {
            if stop() {
                return Err(LinkError::Stopped("worker hosts"));
            }
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(LinkError::TooFewWorkers {
                    joined: self.pending.len(),
                    wanted,
                    secs: timeout.as_secs_f64(),
                });
            }
            let Ok(Some(q)) = self.queryable.recv_timeout(left.min(Duration::from_millis(100)))
            else {
                continue;
            };
            match self.check(&q) {
                Ok(h) => {
                    if let Some(i) = self.pending.iter().position(|(_, p)| p.host == h.host) {
                        if same_token(&self.pending[i].1.token, &h.token) {
                            // The same host asking again (it retried): keep the newest.
                            self.pending[i] = (q, h);
                        } else {
                            refuse(
                                &q,
                                &format!(
                                    "host {} has already joined this run (another join token)",
                                    h.host
                                ),
                            );
                        }
                    } else {
                        tracing::info!(
                            "worker {} joined: {} × {} agents",
                            h.host,
                            h.envs,
                            h.agents
                        );
                        self.pending.push((q, h));
                    }
                }
                Err(why) => refuse(&q, &why),
            }
        }
        let mut env_offset = head_envs as u32;
        self.hosts.clear();
        for (i, (_, h)) in self.pending.iter().enumerate() {
            self.hosts.push(Host {
                name: h.host.clone(),
                slot: i as u32 + 1,
                envs: h.envs,
                agents: h.agents,
                env_offset,
                token: h.token.clone(),
            });
            env_offset += h.envs;
        }
        Ok(self.hosts.clone())
    }

    /// Answers the gathered workers: each gets its place, the config
    /// `welcome` gives it and the arena.
    pub fn admit(&mut self, welcome: impl Fn(&Host) -> (String, String)) {
        for ((q, _), host) in self.pending.drain(..).zip(&self.hosts) {
            let (config, arena) = welcome(host);
            reply(
                &q,
                &Welcome::Joined {
                    slot: host.slot,
                    env_offset: host.env_offset,
                    run: self.run.clone(),
                    config,
                    arena,
                },
            );
        }
    }

    fn check(&self, q: &Query) -> std::result::Result<Hello, String> {
        let bytes = q.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
        let mut h = Hello::decode(&bytes).ok_or("not a rotorhive worker's join request")?;
        if h.agents == 0 {
            h.agents = self.default_agents;
        }
        if h.layout != self.layout {
            return Err("message layout mismatch: this worker runs another build of hive (or another model); run the same build on every host".into());
        }
        if h.envs == 0 || h.agents == 0 {
            return Err(format!(
                "a worker needs at least one environment and one agent, got {} × {}",
                h.envs, h.agents
            ));
        }
        if h.token.is_empty() || h.token.len() > wire::MAX_TOKEN {
            return Err(format!(
                "a join token of 1 to {} bytes is needed, got {}",
                wire::MAX_TOKEN,
                h.token.len()
            ));
        }
        Ok(h)
    }

    /// Starts bridging for the roles of run `prefix` over iceoryx2 service
    /// `S` on this host: a thread that ends (sending the run's end to the
    /// workers) when `stop` is set. `envs` and `roles` size the channels as
    /// the head's roles do; `config_for` gives a returning worker its config.
    pub fn bridge<S: Service>(
        self,
        prefix: String,
        envs: usize,
        roles: usize,
        stop: Arc<AtomicBool>,
        config_for: ConfigFor,
    ) -> Result<HeadLink> {
        let stats = Arc::new(HeadStats::default());
        let (st, sp) = (stats.clone(), stop.clone());
        let hosts = self.hosts.clone();
        let thread = std::thread::Builder::new()
            .name("link".into())
            .spawn(move || {
                let hub = Hub::<S>::new(&prefix, "link")?.with_stop(sp.clone());
                head_loop(&self, &hub, envs, roles, &sp, &st, config_for)
            })
            .map_err(|e| LinkError::Zenoh {
                what: "start the link thread".into(),
                message: e.to_string(),
            })?;
        Ok(HeadLink { thread: Some(thread), stop, stats, hosts })
    }
}

/// Gives a worker that joins again its config and arena.
pub type ConfigFor = Box<dyn Fn(&Host) -> (String, String) + Send>;

fn reply(q: &Query, w: &Welcome) {
    if let Err(e) = q.reply(JOIN, w.encode()).wait() {
        tracing::warn!("cannot answer a worker: {e}");
    }
}

fn refuse(q: &Query, why: &str) {
    tracing::warn!("refused a worker: {why}");
    reply(q, &Welcome::Refused(why.to_string()));
}

/// The running head link.
pub struct HeadLink {
    thread: Option<std::thread::JoinHandle<Result<()>>>,
    stop: Arc<AtomicBool>,
    /// Its counters.
    pub stats: Arc<HeadStats>,
    /// The workers that joined at the start.
    pub hosts: Vec<Host>,
}

impl HeadLink {
    /// Whether the thread ended (with an error: it runs until stopped).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Ends the run on the workers and stops the thread; returns its error.
    pub fn stop(&mut self) -> Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => {
                Err(LinkError::Zenoh { what: "link thread".into(), message: "panicked".into() })
            }
            None => Ok(()),
        }
    }
}

impl Drop for HeadLink {
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

/// Telemetry of a link: stages `receive`, `forward`, `weights`, `send_wait`
/// ([`LinkStage`]), published by the transport's periodic publisher.
type LinkTelemetry<S> = rotorhive_transport::Periodic<S, Telemetry>;

/// The link's telemetry in a run of `roles` roles.
fn link_telemetry<S: Service>(
    hub: &Hub<S>,
    roles: usize,
    index: usize,
) -> Result<LinkTelemetry<S>> {
    let sample = Telemetry {
        role: RoleKind::Link as u32,
        index: index as u32,
        pid: std::process::id(),
        ..Telemetry::default()
    };
    Ok(rotorhive_transport::Periodic::new(hub, &Channel::telemetry(roles), sample)?)
}

/// Sends into shared memory, retrying while the receiver is full (bounded
/// back-pressure, never a loss) until `stop`.
fn send_retrying<S: Service, T, H>(
    tx: &mut rotorhive_transport::Sender<S, T, H>,
    len: usize,
    stop: &AtomicBool,
    mut fill: impl FnMut(&mut H, &mut [T]),
) -> Result<bool>
where
    T: rotorhive_transport::Plain,
    H: std::fmt::Debug + iceoryx2::prelude::ZeroCopySend + Default + 'static,
{
    loop {
        match tx.send_with(len, &mut fill) {
            Ok(()) => return Ok(true),
            Err(TransportError::Stalled { .. })
                if !stop.load(Ordering::SeqCst) && !rotorhive_transport::stop_requested() =>
            {
                continue;
            }
            Err(TransportError::Stalled { .. }) => return Ok(false),
            Err(e) => return Err(e.into()),
        }
    }
}

fn head_loop<S: Service>(
    head: &Head,
    hub: &Hub<S>,
    envs: usize,
    roles: usize,
    stop: &AtomicBool,
    stats: &HeadStats,
    config_for: ConfigFor,
) -> Result<()> {
    let s = &head.session;
    let decl = |what: &str| zerr(format!("declare {what}"));
    let publisher = |what: &str| {
        s.declare_publisher(key(&head.run, what))
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(decl(what))
    };
    let end_pub = publisher("end")?;
    let total_envs = envs + head.hosts.iter().map(|h| h.envs as usize).sum::<usize>();
    let max_batch = rotorhive_msg::PACKED_LEN * check::MAX_BATCH;
    if let Ok(mut l) = stats.lost_by_env.lock() {
        *l = vec![0; total_envs];
    }
    let mut b = HeadBridge {
        head,
        stats,
        stop,
        w_pub: publisher("weights")?,
        trans_tx: hub.sender(&Channel::transitions(envs), max_batch, Duration::from_millis(200))?,
        ep_tx: hub.sender(
            &Channel::episodes(envs),
            EPISODE_FIELDS * 4096,
            Duration::from_millis(200),
        )?,
        w_rx: hub.receiver(&Channel::weights(envs))?,
        tel: link_telemetry(hub, roles, 0)?,
        next_seq: SeqTracker::new(total_envs),
        version: 0,
    };
    while !stop.load(Ordering::SeqCst) && !hub.shutdown_requested() {
        b.weights_out()?;
        // Transitions in, loss-free: the FIFO is bounded and the send waits.
        let t = Instant::now();
        let got = head.subs.transitions.recv_timeout(Duration::from_millis(5)).ok().flatten();
        b.tel.sample.time_stage(LinkStage::Receive, t);
        if let Some(smp) = got {
            b.transitions_in(&smp)?;
        }
        b.episodes_and_telemetry_in();
        b.rejoins(&config_for);
        b.tel.tick(false, Telemetry::beat);
    }
    // The run's end, so the workers exit 0 instead of reporting a lost head.
    let _ = end_pub.put(b"end".to_vec()).wait();
    // Let the message leave before the session closes.
    std::thread::sleep(Duration::from_millis(200));
    Ok(())
}

/// The head's link at work: what it sends and receives on the head's
/// shared memory, and what it keeps between rounds.
struct HeadBridge<'a, S: Service> {
    head: &'a Head,
    stats: &'a HeadStats,
    stop: &'a AtomicBool,
    w_pub: zenoh::pubsub::Publisher<'static>,
    trans_tx: rotorhive_transport::Sender<S, u16, TransitionHeader>,
    ep_tx: rotorhive_transport::Sender<S, f32, EpisodeHeader>,
    w_rx: rotorhive_transport::Receiver<S, f32, WeightsHeader>,
    tel: LinkTelemetry<S>,
    /// The batches seen from each actor of the run.
    next_seq: SeqTracker,
    /// The newest weight version sent.
    version: u64,
}

impl<S: Service> HeadBridge<'_, S> {
    /// Weights out: the newest version, once per host (zenoh fans out).
    fn weights_out(&mut self) -> Result<()> {
        let t = Instant::now();
        if let Some(w) = self.w_rx.latest()? {
            let h = *w.user_header();
            if h.version != self.version {
                self.version = h.version;
                let bytes = wire::payload_bytes(w.payload()).to_vec();
                self.w_pub
                    .put(bytes)
                    .attachment(wire::header_bytes(&h).to_vec())
                    .wait()
                    .map_err(zerr("send weights"))?;
                self.tel.sample.weight_version = self.version;
            }
        }
        self.tel.sample.time_stage(LinkStage::Weights, t);
        Ok(())
    }

    /// One transition batch from a worker: checked, its sequence gap
    /// counted, then into the replay's channel (the send retried while the
    /// replay is full).
    fn transitions_in(&mut self, smp: &zenoh::sample::Sample) -> Result<()> {
        let (stats, hosts, run) = (self.stats, &self.head.hosts, &self.head.run);
        let t = Instant::now();
        let payload = smp.payload();
        let frags: Vec<&[u8]> = payload.slices().collect();
        let Some(h) = accept(stats, hosts, smp, run, "transitions", |host, att| {
            check::transitions(host, att, &frags)
        }) else {
            return Ok(());
        };
        let words = payload.len() / 2;
        let gap = self.next_seq.observe(h.actor as usize, h.seq);
        if gap > 0 {
            tracing::warn!(
                "head link: actor {} batches {}..{} missing",
                h.actor,
                h.seq - gap,
                h.seq
            );
            stats.lost_batches.fetch_add(gap, Ordering::Relaxed);
            stats.lost_transitions.fetch_add(gap.saturating_mul(h.count as u64), Ordering::Relaxed);
            self.tel.sample.lost = self.tel.sample.lost.saturating_add(gap);
            if let Some(l) =
                stats.lost_by_env.lock().ok().as_mut().and_then(|v| v.get_mut(h.actor as usize))
            {
                *l = l.saturating_add(gap.saturating_mul(h.count as u64));
            }
        }
        let sent = send_retrying(&mut self.trans_tx, words, self.stop, |hdr, p| {
            *hdr = h;
            // Zenoh's fragments straight into the loaned sample (their
            // total is the sample's length: checked above).
            let out = wire::payload_bytes_mut(p);
            let mut at = 0;
            for frag in &frags {
                out[at..at + frag.len()].copy_from_slice(frag);
                at += frag.len();
            }
        })?;
        if sent {
            stats.batches.fetch_add(1, Ordering::Relaxed);
            stats.transitions.fetch_add(h.count as u64, Ordering::Relaxed);
            self.tel.sample.work += h.count as u64;
            self.tel.sample.work2 += payload.len() as u64;
        }
        self.tel.sample.time_stage(LinkStage::SendWait, t);
        Ok(())
    }

    /// The workers' episodes and telemetry, checked, into the head's
    /// records (episodes that find the channel full are counted dropped).
    fn episodes_and_telemetry_in(&mut self) {
        let (stats, hosts, run) = (self.stats, &self.head.hosts, &self.head.run);
        let t = Instant::now();
        while let Ok(Some(smp)) = self.head.subs.episodes.try_recv() {
            let bytes = smp.payload().to_bytes();
            let Some(h) = accept(stats, hosts, &smp, run, "episodes", |host, att| {
                check::episodes(host, att, &bytes)
            }) else {
                continue;
            };
            if self
                .ep_tx
                .send_with(bytes.len() / 4, |hdr, p| {
                    *hdr = h;
                    wire::payload_bytes_mut(p).copy_from_slice(&bytes);
                })
                .is_err()
            {
                stats.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
        while let Ok(Some(smp)) = self.head.subs.telemetry.try_recv() {
            if let Some(t) = accept(stats, hosts, &smp, run, "telemetry", |host, att| {
                check::telemetry(host, att, smp.payload().len())
            }) {
                self.tel.send(t);
            }
        }
        self.tel.sample.time_stage(LinkStage::Forward, t);
    }

    /// A worker that comes back (restarted) with its join token gets its
    /// old place; anyone else is refused.
    fn rejoins(&mut self, config_for: &ConfigFor) {
        let (head, run) = (self.head, &self.head.run);
        while let Ok(Some(q)) = head.queryable.try_recv() {
            match head.check(&q) {
                Ok(h) => match head.hosts.iter().find(|x| x.name == h.host) {
                    Some(x) if !same_token(&x.token, &h.token) => refuse(
                        &q,
                        &format!(
                            "host {} is in this run; only the worker that joined under that name (with its join token) may take its place back",
                            x.name
                        ),
                    ),
                    Some(x) if x.envs == h.envs && x.agents == h.agents => {
                        let (config, arena) = config_for(x);
                        reply(
                            &q,
                            &Welcome::Joined {
                                slot: x.slot,
                                env_offset: x.env_offset,
                                run: run.clone(),
                                config,
                                arena,
                            },
                        );
                        // Its actors start their sequences afresh.
                        for e in x.env_offset as usize..(x.env_offset + x.envs) as usize {
                            self.next_seq.reset(e);
                        }
                        tracing::info!("worker {} joined again", x.name);
                    }
                    Some(x) => refuse(
                        &q,
                        &format!(
                            "host {} joined with {} × {} agents, and comes back with {} × {}",
                            x.name, x.envs, x.agents, h.envs, h.agents
                        ),
                    ),
                    None => refuse(&q, "the run has all its worker hosts (`cluster.workers`)"),
                },
                Err(why) => refuse(&q, &why),
            }
        }
    }
}

/// A message `what` from another host, checked by `check` against the
/// joined host its key names, with its attachment; one that fails (or
/// whose key names no host: slot 0) is counted against its sender and `None`.
fn accept<T>(
    stats: &HeadStats,
    hosts: &[Host],
    smp: &zenoh::sample::Sample,
    run: &str,
    what: &str,
    check: impl FnOnce(&Host, Option<&[u8]>) -> std::result::Result<T, check::Reject>,
) -> Option<T> {
    let Some(host) = check::slot_of(smp.key_expr().as_str(), run, what)
        .and_then(|slot| hosts.iter().find(|h| h.slot == slot))
    else {
        stats.reject(0, what, &check::Reject::UnknownSender);
        return None;
    };
    let att = smp.attachment().map(|a| a.to_bytes());
    check(host, att.as_deref()).map_err(|why| stats.reject(host.slot, what, &why)).ok()
}

/// How a worker's link ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorkerEnd {
    /// The head ended the run.
    RunEnded,
    /// This process was asked to stop.
    Stopped,
}

/// Counters of a worker's link.
#[derive(Debug, Default, Clone, Copy)]
pub struct WorkerStats {
    /// Transition batches sent.
    pub batches: u64,
    /// Transitions sent.
    pub transitions: u64,
    /// Weight versions received.
    pub weights: u64,
    /// Newest weight version received.
    pub weight_version: u64,
    /// Episode or telemetry messages dropped.
    pub dropped: u64,
    /// Weights from the head that failed their check and were dropped.
    pub rejected: u64,
}

/// A worker's end of the link.
pub struct Worker {
    session: zenoh::Session,
    /// The head's answer.
    pub slot: u32,
    /// Index of this host's first environment in the run.
    pub env_offset: u32,
    /// The run's name.
    pub run: String,
    /// The head's resolved config (TOML).
    pub config: String,
    /// The training arena (TOML).
    pub arena: String,
}

impl Worker {
    /// Connects to the head at `endpoint` and joins its run, asking again
    /// until `timeout` (the head may start later than the worker).
    pub fn join(
        endpoint: &str,
        hello: &Hello,
        timeout: Duration,
        opts: &LinkOptions,
        stop: impl Fn() -> bool,
    ) -> Result<Self> {
        let session = open(None, Some(endpoint), opts)?;
        let start = Instant::now();
        while start.elapsed() < timeout {
            if stop() {
                return Err(LinkError::Stopped("the head"));
            }
            let left = timeout.saturating_sub(start.elapsed()).max(Duration::from_millis(100));
            let replies = session
                .get(JOIN)
                .payload(hello.encode())
                .timeout(left.min(Duration::from_secs(5)))
                .wait()
                .map_err(zerr("ask to join"))?;
            // Every answer ends the wait; none means nobody is there yet.
            if let Ok(r) = replies.recv() {
                let bytes = match r.result() {
                    Ok(s) => s.payload().to_bytes().into_owned(),
                    Err(e) => {
                        return Err(LinkError::Refused {
                            endpoint: endpoint.into(),
                            why: String::from_utf8_lossy(&e.payload().to_bytes()).into_owned(),
                        });
                    }
                };
                match Welcome::decode(&bytes) {
                    Some(Welcome::Joined { slot, env_offset, run, config, arena }) => {
                        return Ok(Self { session, slot, env_offset, run, config, arena });
                    }
                    Some(Welcome::Refused(why)) => {
                        return Err(LinkError::Refused { endpoint: endpoint.into(), why });
                    }
                    None => {
                        return Err(LinkError::Refused {
                            endpoint: endpoint.into(),
                            why: "an answer that is not a rotorhive welcome".into(),
                        });
                    }
                }
            }
            // The session keeps trying to connect meanwhile.
            std::thread::sleep(Duration::from_millis(200));
        }
        Err(LinkError::NoHead { endpoint: endpoint.into(), secs: timeout.as_secs_f64() })
    }

    /// Bridges this host's sims and actors (run `prefix` over service `S`,
    /// `envs` environments, `roles` telemetry publishers) to the head until
    /// the head ends the run, the head is lost, or this process stops.
    /// `on_ready` runs once the link takes this host's batches and the head
    /// takes the link's: start the actors then, or their first batches go
    /// nowhere.
    /// Weights that are not `num_params` finite floats are dropped.
    pub fn bridge<S: Service>(
        &self,
        hub: &Hub<S>,
        envs: usize,
        roles: usize,
        num_params: usize,
        stats: &mut WorkerStats,
        on_ready: impl FnOnce(),
    ) -> Result<WorkerEnd> {
        let s = &self.session;
        let run = &self.run;
        let decl = |what: &str| zerr(format!("declare {what}"));
        let publisher = |what: &str, cc| {
            s.declare_publisher(host_key(run, self.slot, what))
                .congestion_control(cc)
                .wait()
                .map_err(decl(what))
        };
        let mut b = WorkerBridge {
            trans_pub: publisher("transitions", CongestionControl::Block)?,
            ep_pub: publisher("episodes", CongestionControl::Drop)?,
            tel_pub: publisher("telemetry", CongestionControl::Drop)?,
            w_sub: s
                .declare_subscriber(key(run, "weights"))
                .with(RingChannel::new(1))
                .wait()
                .map_err(decl("the weights subscriber"))?,
            end_sub: s
                .declare_subscriber(key(run, "end"))
                .with(FifoChannel::new(4))
                .wait()
                .map_err(decl("the end subscriber"))?,
            head_sub: s
                .liveliness()
                .declare_subscriber(key(run, "head"))
                .history(true)
                .with(FifoChannel::new(16))
                .wait()
                .map_err(decl("the head's liveliness"))?,
            trans_rx: hub.receiver(&Channel::transitions(envs))?,
            ep_rx: hub.receiver(&Channel::episodes(envs))?,
            tel_rx: hub.receiver(&Channel::telemetry(roles))?,
            w_tx: None,
            tel: link_telemetry(hub, roles, 0)?,
            wseq: SeqTracker::new(envs),
            head_seen: false,
            off: self.env_offset,
            slot: self.slot,
            envs,
            num_params,
        };
        let _token = s
            .liveliness()
            .declare_token(key(run, &format!("host/{}", self.slot)))
            .wait()
            .map_err(decl("this host's liveliness"))?;
        // Zenoh drops what no subscriber matches: send nothing before the
        // head's transitions subscriber is known here.
        let t = Instant::now();
        while !b.trans_pub.matching_status().wait().map_err(zerr("matching status"))?.matching() {
            if t.elapsed() > Duration::from_secs(20) {
                return Err(LinkError::LostHead);
            }
            if hub.shutdown_requested() {
                return Ok(WorkerEnd::Stopped);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        on_ready();
        loop {
            if hub.shutdown_requested() {
                return Ok(WorkerEnd::Stopped);
            }
            if let Some(end) = b.head_end() {
                return end;
            }
            b.weights_in(hub, stats)?;
            b.transitions_out(stats)?;
            b.episodes_and_telemetry_out(stats)?;
            b.tel.tick(false, Telemetry::beat);
        }
    }
}

/// A worker's link at work: its Zenoh publishers and subscribers, its
/// host's shared-memory channels, and what it keeps between rounds.
struct WorkerBridge<S: Service> {
    trans_pub: zenoh::pubsub::Publisher<'static>,
    ep_pub: zenoh::pubsub::Publisher<'static>,
    tel_pub: zenoh::pubsub::Publisher<'static>,
    w_sub: zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<zenoh::sample::Sample>>,
    end_sub: Fifo,
    head_sub: Fifo,
    trans_rx: rotorhive_transport::Receiver<S, u16, TransitionHeader>,
    ep_rx: rotorhive_transport::Receiver<S, f32, EpisodeHeader>,
    tel_rx: rotorhive_transport::Receiver<S, u8, Telemetry>,
    w_tx: Option<rotorhive_transport::Sender<S, f32, WeightsHeader>>,
    tel: LinkTelemetry<S>,
    /// The batches seen from each actor of this host.
    wseq: SeqTracker,
    head_seen: bool,
    off: u32,
    slot: u32,
    envs: usize,
    num_params: usize,
}

impl<S: Service> WorkerBridge<S> {
    /// The run's end, or the head lost (its liveliness token gone without
    /// the end message right behind it); none while the head is there.
    fn head_end(&mut self) -> Option<Result<WorkerEnd>> {
        if self.end_sub.try_recv().ok().flatten().is_some() {
            return Some(Ok(WorkerEnd::RunEnded));
        }
        while let Ok(Some(l)) = self.head_sub.try_recv() {
            match l.kind() {
                SampleKind::Put => self.head_seen = true,
                SampleKind::Delete if self.head_seen => {
                    // The end message may be right behind (over TLS on a
                    // busy machine, up to a few hundred ms): look for 1 s.
                    let t = Instant::now();
                    while t.elapsed() < Duration::from_secs(1) {
                        if self
                            .end_sub
                            .recv_timeout(Duration::from_millis(50))
                            .ok()
                            .flatten()
                            .is_some()
                        {
                            return Some(Ok(WorkerEnd::RunEnded));
                        }
                    }
                    return Some(Err(LinkError::LostHead));
                }
                SampleKind::Delete => {}
            }
        }
        None
    }

    /// The newest weights in, checked, republished on this host.
    fn weights_in(&mut self, hub: &Hub<S>, stats: &mut WorkerStats) -> Result<()> {
        let t = Instant::now();
        if let Ok(Some(smp)) = self.w_sub.try_recv() {
            let bytes = smp.payload().to_bytes();
            match check::weights(
                self.num_params,
                smp.attachment().map(|a| a.to_bytes()).as_deref(),
                &bytes,
            ) {
                Ok(h) => {
                    if self.w_tx.is_none() {
                        self.w_tx = Some(hub.sender::<f32, WeightsHeader>(
                            &Channel::weights(self.envs),
                            self.num_params,
                            Duration::from_millis(200),
                        )?);
                    }
                    if let Some(tx) = self.w_tx.as_mut() {
                        tx.send_with(self.num_params, |hdr, p| {
                            *hdr = h;
                            wire::payload_bytes_mut(p).copy_from_slice(&bytes);
                        })?;
                    }
                    stats.weights += 1;
                    stats.weight_version = h.version;
                    self.tel.sample.weight_version = h.version;
                }
                Err(why) => {
                    stats.rejected += 1;
                    tracing::warn!("dropped weights from the head: {why}");
                }
            }
        }
        self.tel.sample.time_stage(LinkStage::Weights, t);
        Ok(())
    }

    /// One transition batch out, if there is one: a blocking put, so a busy
    /// head slows the actors.
    fn transitions_out(&mut self, stats: &mut WorkerStats) -> Result<()> {
        let t = Instant::now();
        let m = self.trans_rx.recv_timeout(Duration::from_millis(5))?;
        self.tel.sample.time_stage(LinkStage::Receive, t);
        let Some(m) = m else { return Ok(()) };
        let t = Instant::now();
        let mut h = *m.user_header();
        let gap = self.wseq.observe(h.actor as usize, h.seq);
        if gap > 0 {
            tracing::warn!(
                "worker link: actor {} batches {}..{} missing in shared memory",
                h.actor,
                h.seq - gap,
                h.seq
            );
        }
        h.actor += self.off;
        self.trans_pub
            .put(wire::payload_bytes(m.payload()).to_vec())
            .attachment(wire::header_bytes(&h).to_vec())
            .wait()
            .map_err(zerr("send transitions"))?;
        stats.batches += 1;
        stats.transitions += h.count as u64;
        self.tel.sample.work += h.count as u64;
        self.tel.sample.work2 += std::mem::size_of_val(m.payload()) as u64;
        self.tel.sample.time_stage(LinkStage::SendWait, t);
        Ok(())
    }

    /// Episodes and telemetry out (they may drop under load: counted), with
    /// this host's environment offset and slot.
    fn episodes_and_telemetry_out(&mut self, stats: &mut WorkerStats) -> Result<()> {
        let t = Instant::now();
        while let Some(m) = self.ep_rx.try_recv()? {
            let mut h = *m.user_header();
            h.actor += self.off;
            if self
                .ep_pub
                .put(wire::payload_bytes(m.payload()).to_vec())
                .attachment(wire::header_bytes(&h).to_vec())
                .wait()
                .is_err()
            {
                stats.dropped += 1;
            }
        }
        while let Some(m) = self.tel_rx.try_recv()? {
            let mut t = *m.user_header();
            if t.role == RoleKind::Link as u32 {
                t.index = self.slot;
            } else {
                t.index += self.off;
            }
            // A process id means nothing on the head's host.
            t.pid = 0;
            if self
                .tel_pub
                .put(Vec::new())
                .attachment(wire::header_bytes(&t).to_vec())
                .wait()
                .is_err()
            {
                stats.dropped += 1;
            }
        }
        self.tel.sample.time_stage(LinkStage::Forward, t);
        Ok(())
    }
}
