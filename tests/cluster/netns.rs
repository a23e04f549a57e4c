//! Two "hosts" on one machine: two network namespaces joined by a veth
//! pair (root only), a head in one and a worker in the other.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

use crate::common::{root, tmp};
use crate::small_run;

/// Two network namespaces joined by a veth pair, removed on drop.
pub struct NetPair {
    a: String,
    b: String,
}

impl NetPair {
    fn new() -> Result<Self, String> {
        let id = std::process::id() % 100_000;
        let (a, b) = (format!("rha{id}"), format!("rhb{id}"));
        let run = |args: &[&str]| -> Result<(), String> {
            let o =
                Command::new("ip").args(args).output().map_err(|e| format!("ip {args:?}: {e}"))?;
            if o.status.success() {
                Ok(())
            } else {
                Err(format!("ip {args:?}: {}", String::from_utf8_lossy(&o.stderr).trim()))
            }
        };
        let pair = Self { a: a.clone(), b: b.clone() };
        let (va, vb) = (format!("va{id}"), format!("vb{id}"));
        run(&["netns", "add", &a])?;
        run(&["netns", "add", &b])?;
        run(&["link", "add", &va, "type", "veth", "peer", "name", &vb])?;
        run(&["link", "set", &va, "netns", &a])?;
        run(&["link", "set", &vb, "netns", &b])?;
        run(&["-n", &a, "addr", "add", "10.78.0.1/24", "dev", &va])?;
        run(&["-n", &b, "addr", "add", "10.78.0.2/24", "dev", &vb])?;
        for (ns, dev) in [(&a, &va), (&b, &vb)] {
            run(&["-n", ns, "link", "set", "lo", "up"])?;
            run(&["-n", ns, "link", "set", dev, "up"])?;
        }
        Ok(pair)
    }

    /// Takes the second namespace's end of the veth pair down or up (a
    /// network outage for the host there).
    pub fn set_link(&self, up: bool) -> Result<(), String> {
        let dev = format!("vb{}", self.b.trim_start_matches("rhb"));
        let state = if up { "up" } else { "down" };
        let o = Command::new("ip")
            .args(["-n", &self.b, "link", "set", &dev, state])
            .output()
            .map_err(|e| e.to_string())?;
        if o.status.success() {
            Ok(())
        } else {
            Err(String::from_utf8_lossy(&o.stderr).into_owned())
        }
    }

    /// `hive args` inside namespace `ns`, with a /dev/shm of its own.
    fn hive(&self, ns: &str, args: &[&str]) -> Command {
        let mut line =
            format!("mount -t tmpfs none /dev/shm && exec {}", env!("CARGO_BIN_EXE_hive"));
        for a in args {
            line.push_str(&format!(" '{a}'"));
        }
        let mut c = Command::new("ip");
        c.current_dir(root()).args([
            "netns",
            "exec",
            ns,
            "unshare",
            "-m",
            "--propagation",
            "private",
            "sh",
            "-c",
            &line,
        ]);
        c.stdout(Stdio::piped()).stderr(Stdio::piped());
        c
    }
}

impl Drop for NetPair {
    fn drop(&mut self) {
        for ns in [&self.a, &self.b] {
            let _ = Command::new("ip").args(["netns", "del", ns]).output();
        }
    }
}

/// A head (`--max-seconds secs`, run directory `tmp(name)`) in one network
/// namespace and a worker named `worker` (8 agents) in the other, both
/// started with `link` (their link's options); `None` (saying why) where
/// namespaces cannot be made here.
pub fn netns_run(
    name: &str,
    secs: &str,
    worker: &str,
    link: &[&str],
) -> Option<(NetPair, PathBuf, Child, Child)> {
    if !rustix::process::geteuid().is_root() {
        println!("skipped: network namespaces need root");
        return None;
    }
    let net = match NetPair::new() {
        Ok(n) => n,
        Err(e) => {
            println!("skipped: cannot make two network namespaces here: {e}");
            return None;
        }
    };
    let dir = tmp(name);
    let dir_s = dir.display().to_string();
    let ep = "tcp/10.78.0.1:7447";
    let mut args =
        vec!["train", "--listen", ep, "--insecure", "--max-seconds", secs, "--run-dir", &dir_s];
    args.extend(small_run());
    args.extend(["--set", "cluster.workers=1"]);
    args.extend(link);
    let head = net.hive(&net.a, &args).spawn().unwrap();
    let wdir = tmp(&format!("{name}-worker")).display().to_string();
    let mut wargs =
        vec!["worker", "--connect", ep, "--agents", "8", "--name", worker, "--run-dir", &wdir];
    wargs.extend(link);
    let worker = net.hive(&net.b, &wargs).spawn().unwrap();
    Some((net, dir, head, worker))
}
