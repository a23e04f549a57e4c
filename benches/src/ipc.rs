//! `hive bench ipc`: moves a 50-agent observation batch, a 50-transition
//! batch and the network's weights between two processes, through
//! rotorhive's transport (iceoryx2 shared memory: the sender fills a loaned
//! sample, the receiver reads it in place) and through the paper's path
//! (msgpack over a loopback TCP connection, as PRL4AirSim's RPC did), side by
//! side in one run. Each message is answered by a small acknowledgement;
//! latency is half the round trip.
//!
//! Where the clock starts: when the message is ready where its producer
//! writes it. In rotorhive that is the loaned sample itself (the sim
//! assembles its observations there, the actor packs its transitions there,
//! the learner writes its weights there), so the shared-memory time starts
//! once the loan is filled; over RPC it is the producer's own buffer, so the
//! msgpack time includes serializing it. The shared-memory time with a copy
//! of a finished buffer into the loan is reported beside it.

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::error::{Doing, Result, failed, usage};
use rotorhive_msg::{ActionHeader, ObsHeader, Shapes};

const OBS_LEN: usize = Shapes::PAPER.obs_len();
const PACKED_LEN: usize = Shapes::PAPER.packed_len();
use rotorhive_transport::{Channel, Hub, Ipc, services_of_run};
use serde::{Deserialize, Serialize};
use serde_json::json;

/// The three payloads, in floats (a transition batch: the bytes of 50
/// packed transitions).
fn kinds() -> [(&'static str, usize); 4] {
    [
        ("obs_batch", Shapes::PAPER.obs_batch_len(50)),
        ("transition_batch", 50 * PACKED_LEN / 2),
        ("weights", rotorhive_model::num_params(Shapes::PAPER, Default::default())),
        ("empty", 1),
    ]
}

fn request_channel() -> Channel {
    bench_channel("bench.req")
}

fn ack_channel() -> Channel {
    bench_channel("bench.ack")
}

/// One writer, one reader, two messages in flight.
fn bench_channel(name: &str) -> Channel {
    Channel {
        name: name.into(),
        publishers: 1,
        subscribers: 1,
        buffer: 2,
        overflow: false,
        history: 0,
        needs_receiver: false,
    }
}

/// What PRL4AirSim's msgpack-RPC carried: a typed record with a float array.
#[derive(Deserialize)]
struct RpcMsg {
    kind: u32,
    seq: u64,
    data: Vec<f32>,
}

/// The sender's side of [`RpcMsg`]: it serializes from its own buffer
/// without copying it first (same bytes on the wire).
#[derive(Serialize)]
struct RpcMsgRef<'a> {
    kind: u32,
    seq: u64,
    data: &'a [f32],
}

#[derive(Serialize, Deserialize)]
struct RpcAck {
    seq: u64,
    checksum: f32,
}

const TIMEOUT: Duration = Duration::from_secs(5);

/// Writes one length-prefixed message (a little-endian `u32` length, then
/// the bytes): the framing of the msgpack baselines.
pub(crate) fn write_frame(s: &mut impl std::io::Write, bytes: &[u8]) -> std::io::Result<()> {
    s.write_all(&(bytes.len() as u32).to_le_bytes())?;
    s.write_all(bytes)
}

/// Reads one length-prefixed message into `buf`; `false` when the peer
/// closed the connection between messages.
pub(crate) fn read_frame(s: &mut impl std::io::Read, buf: &mut Vec<u8>) -> std::io::Result<bool> {
    let mut len = [0u8; 4];
    if s.read_exact(&mut len).is_err() {
        return Ok(false);
    }
    buf.resize(u32::from_le_bytes(len) as usize, 0);
    s.read_exact(buf)?;
    Ok(true)
}

/// The far side: answers every message (shared memory and TCP) with an
/// acknowledgement carrying a checksum of what it read.
pub fn peer(prefix: &str) -> Result<()> {
    let hub = Hub::<Ipc>::new(prefix, "bench-peer")?;
    let mut rx = hub.receiver::<f32, ObsHeader>(&request_channel())?;
    let mut tx = hub.sender::<u8, ActionHeader>(&ack_channel(), 1, TIMEOUT)?;
    let listener = TcpListener::bind("127.0.0.1:0").doing("binding a loopback port")?;
    println!("{}", listener.local_addr()?.port());
    std::io::stdout().flush()?;
    // Shared memory first, until the parent sends the end marker.
    loop {
        let Some(m) = rx.recv_timeout(TIMEOUT)? else {
            failed!("no message from the benchmark for {TIMEOUT:?}")
        };
        let h = *m.user_header();
        if h.agents == u32::MAX {
            break;
        }
        let p = m.payload();
        let sum = p[0] + p[p.len() - 1];
        drop(m);
        tx.send_with(1, |a, out| {
            *a = ActionHeader { step: h.step };
            out[0] = (sum != 0.0) as u8;
        })?;
    }
    // Then TCP with msgpack.
    let (mut s, _) = listener.accept()?;
    s.set_nodelay(true)?;
    let mut buf = Vec::new();
    while read_frame(&mut s, &mut buf)? {
        let m: RpcMsg = rmp_serde::from_slice(&buf).doing("decoding msgpack")?;
        if m.kind as usize >= kinds().len() || m.data.is_empty() {
            failed!("msgpack message {} of unknown kind {} or empty", m.seq, m.kind);
        }
        let ack = rmp_serde::to_vec(&RpcAck {
            seq: m.seq,
            checksum: m.data[0] + m.data[m.data.len() - 1],
        })?;
        write_frame(&mut s, &ack)?;
    }
    Ok(())
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    crate::stats::quantile(v, q)
}

struct Stats {
    p50: f64,
    p90: f64,
    p99: f64,
    per_s: f64,
}

fn stats(mut half_rtt_us: Vec<f64>, wall: f64) -> Stats {
    let n = half_rtt_us.len();
    Stats {
        p50: percentile(&mut half_rtt_us, 0.5),
        p90: percentile(&mut half_rtt_us, 0.9),
        p99: percentile(&mut half_rtt_us, 0.99),
        per_s: n as f64 / wall,
    }
}

/// Each kind of message through shared memory to the peer and back,
/// `iters` times: (latency from the filled loan, latency with the copy in).
fn shm_rows(
    tx: &mut rotorhive_transport::Sender<Ipc, f32, ObsHeader>,
    rx: &mut rotorhive_transport::Receiver<Ipc, u8, ActionHeader>,
    sources: &[Vec<f32>],
    iters: usize,
) -> Result<Vec<(Stats, Stats)>> {
    let mut shm = Vec::new();
    for (k, (_, n)) in kinds().iter().enumerate() {
        let src = &sources[k];
        let (mut lat, mut lat_copy) = (Vec::with_capacity(iters), Vec::with_capacity(iters));
        let warm = 20;
        let mut t_all = Instant::now();
        for i in 0..iters + warm {
            if i == warm {
                t_all = Instant::now();
            }
            let t = Instant::now();
            let mut ready = t;
            tx.send_with(*n, |h, p| {
                *h = ObsHeader { agents: k as u32, step: i as u64, ..ObsHeader::default() };
                p.copy_from_slice(src);
                ready = Instant::now();
            })?;
            let m = rx.recv_timeout(TIMEOUT)?.doing("no acknowledgement from the peer")?;
            if m.user_header().step != i as u64 || m.payload()[0] != 1 {
                failed!("wrong acknowledgement");
            }
            if i >= warm {
                lat.push(ready.elapsed().as_secs_f64() * 1e6 / 2.0);
                lat_copy.push(t.elapsed().as_secs_f64() * 1e6 / 2.0);
            }
        }
        let wall = t_all.elapsed().as_secs_f64();
        shm.push((stats(lat, wall), stats(lat_copy, wall)));
    }
    Ok(shm)
}

/// Each kind of message serialized with msgpack over one TCP connection to
/// the peer at `port` and acknowledged, `iters` times.
fn tcp_rows(port: u16, sources: &[Vec<f32>], iters: usize) -> Result<Vec<Stats>> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).doing("connecting to the peer")?;
    s.set_nodelay(true)?;
    let mut tcp = Vec::new();
    let mut buf = Vec::new();
    for (k, _) in kinds().iter().enumerate() {
        let mut lat = Vec::with_capacity(iters);
        let warm = 5;
        let mut t_all = Instant::now();
        for i in 0..iters + warm {
            if i == warm {
                t_all = Instant::now();
            }
            let t = Instant::now();
            // The sender's data lives in its own buffers, as in the sim;
            // it is serialized from there, not cloned first.
            let msg =
                rmp_serde::to_vec(&RpcMsgRef { kind: k as u32, seq: i as u64, data: &sources[k] })?;
            write_frame(&mut s, &msg)?;
            if !read_frame(&mut s, &mut buf)? {
                failed!("the TCP peer closed the connection");
            }
            let ack: RpcAck = rmp_serde::from_slice(&buf)?;
            if ack.seq != i as u64 {
                failed!("wrong TCP acknowledgement");
            }
            if i >= warm {
                lat.push(t.elapsed().as_secs_f64() * 1e6 / 2.0);
            }
        }
        tcp.push(stats(lat, t_all.elapsed().as_secs_f64()));
    }
    drop(s);
    Ok(tcp)
}

/// Prints the table and returns its rows as JSON.
fn print_rows(shm: &[(Stats, Stats)], tcp: &[Stats]) -> Vec<serde_json::Value> {
    println!(
        "{:>17} {:>8} {:>11} {:>11} {:>10} {:>16} {:>15} {:>15} {:>11} {:>7} {:>12}",
        "message",
        "KiB",
        "shm p50 µs",
        "shm p99 µs",
        "shm msg/s",
        "+copy-in p50 µs",
        "msgpack p50 µs",
        "msgpack p99 µs",
        "msgpack/s",
        "ratio",
        "ratio +copy"
    );
    let mut rows = Vec::new();
    for (k, (name, n)) in kinds().iter().enumerate() {
        let ((a, c), b) = (&shm[k], &tcp[k]);
        let (ratio, ratio_copy) = (b.p50 / a.p50, b.p50 / c.p50);
        println!(
            "{name:>17} {:>8.1} {:>11.1} {:>11.1} {:>10.0} {:>16.1} {:>15.1} {:>15.1} {:>11.0} {:>6.0}x {:>11.0}x",
            *n as f64 * 4.0 / 1024.0,
            a.p50,
            a.p99,
            a.per_s,
            c.p50,
            b.p50,
            b.p99,
            b.per_s,
            ratio,
            ratio_copy
        );
        rows.push(json!({
            "name": name, "bytes": n * 4,
            "shm_p50_us": a.p50, "shm_p90_us": a.p90, "shm_p99_us": a.p99, "shm_msgs_per_s": a.per_s,
            "shm_copy_in_p50_us": c.p50, "shm_copy_in_p99_us": c.p99,
            "baseline_p50_us": b.p50, "baseline_p90_us": b.p90, "baseline_p99_us": b.p99, "baseline_msgs_per_s": b.per_s,
            "ratio": ratio, "ratio_with_copy_in": ratio_copy,
        }));
    }
    rows
}

pub fn run(iters: usize, json_out: bool) -> Result<()> {
    if iters == 0 {
        usage!("--iters must be positive");
    }
    let prefix = rotorhive_transport::unique_prefix("bench-ipc");
    let hub = Hub::<Ipc>::new(&prefix, "bench")?;
    let max = kinds().iter().map(|k| k.1).max().unwrap_or(1);
    let mut tx = hub.sender::<f32, ObsHeader>(&request_channel(), max, TIMEOUT)?;
    let mut rx = hub.receiver::<u8, ActionHeader>(&ack_channel())?;
    let exe = std::env::current_exe()?;
    let mut child = Command::new(exe)
        .args(["bench", "ipc-peer", "--prefix", &prefix])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .doing("starting the peer process")?;
    let result = (|| -> Result<Vec<serde_json::Value>> {
        let mut line = String::new();
        BufReader::new(child.stdout.take().doing("peer stdout")?).read_line(&mut line)?;
        let port: u16 = line
            .trim()
            .parse()
            .doing_with(|| format!("peer printed {line:?} instead of a port"))?;
        let sources: Vec<Vec<f32>> = kinds()
            .iter()
            .map(|(_, n)| (0..*n).map(|i| (i % 97) as f32 * 0.01 + 0.5).collect())
            .collect();
        let shm = shm_rows(&mut tx, &mut rx, &sources, iters)?;
        tx.send_with(1, |h, _| *h = ObsHeader { agents: u32::MAX, ..ObsHeader::default() })?;
        let tcp = tcp_rows(port, &sources, iters)?;
        let rows = print_rows(&shm, &tcp);
        Ok(rows)
    })();
    let status = child.wait();
    drop(tx);
    drop(rx);
    drop(hub);
    let rows = result?;
    status?;
    let left = services_of_run::<Ipc>(&prefix);
    if !left.is_empty() {
        failed!("shared memory left behind: {left:?}");
    }
    println!(
        "latency = half the round trip (message + 1-byte acknowledgement), from the message being ready where its producer writes it: shm from the filled loan (rotorhive's roles write their messages in place), msgpack from the sender's buffer (serializing included); +copy-in: shm from a finished buffer copied into the loan; the \"empty\" row is the transport's own share (a 4-byte payload); {iters} messages per row"
    );
    if json_out {
        let get = |name: &str| rows.iter().find(|r| r["name"] == name).cloned().unwrap_or_default();
        println!(
            "{}",
            json!({
                "iters": iters,
                "obs_batch": get("obs_batch"),
                "transition_batch": get("transition_batch"),
                "weights": get("weights"),
                "transport_only": get("empty"),
                "transport_only_p50_us": get("empty")["shm_p50_us"],
                "obs_len": OBS_LEN,
            })
        );
    }
    Ok(())
}
