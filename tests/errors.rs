//! The error rule (ARCHITECTURE.md): a cause is part of its error's text
//! and never also its `source()`, so `error: {e:#}` names every cause once.
//! Builds one error of each library's kinds that carry a cause, wrapped as
//! the roles and the benches wrap them, and checks every link of the chain.

use std::error::Error;

use rotorhive_bench::error::BenchError;
use rotorhive_link::LinkError;
use rotorhive_model::ModelError;
use rotorhive_records::RecordsError;
use rotorhive_replay::SnapshotError;
use rotorhive_roles::error::{Doing, RoleError};
use rotorhive_sim::{ArenaError, GpuError, LanesError};
use rotorhive_transport::TransportError;

fn io(text: &str) -> std::io::Error {
    std::io::Error::other(text.to_string())
}

/// One error of every kind that carries a cause, each cause's text unique.
fn errors() -> Vec<(&'static str, Box<dyn Error + Send + Sync>)> {
    let arena = || ArenaError::Io { file: "a.toml".into(), cause: io("arena cause") };
    let transport = || TransportError::Node { node: "n".into(), cause: io("iox cause").into() };
    let snapshot = || SnapshotError::Io { file: "replay.bin".into(), cause: io("snap cause") };
    let model = || ModelError::from(candle_core::Error::Msg("candle cause".into()));
    let gpu = || GpuError::Readback(io("gpu cause").into());
    let json = serde_json::from_str::<u8>("x").unwrap_err();
    let role_while: Result<(), RoleError> = Err(transport()).doing("sending a minibatch");
    vec![
        ("arena", Box::new(arena())),
        ("lanes", Box::new(LanesError::Arena(arena()))),
        ("gpu", Box::new(gpu())),
        ("transport", Box::new(transport())),
        ("snapshot", Box::new(snapshot())),
        ("model", Box::new(model())),
        (
            "records io",
            Box::new(RecordsError::Io { action: "read", file: "f".into(), err: io("rec") }),
        ),
        ("records summary", Box::new(RecordsError::Summary { file: "s.json".into(), err: json })),
        (
            "link zenoh",
            Box::new(LinkError::Zenoh { what: "open".into(), cause: "zenoh cause".into() }),
        ),
        ("link transport", Box::new(LinkError::Transport(transport()))),
        ("role while", Box::new(role_while.unwrap_err())),
        ("role arena", Box::new(RoleError::from(arena()))),
        ("role model", Box::new(RoleError::from(model()))),
        ("role snapshot", Box::new(RoleError::from(snapshot()))),
        ("role gpu", Box::new(RoleError::from(gpu()))),
        ("role io", Box::new(RoleError::from(io("role io cause")))),
        ("bench role", Box::new(BenchError::from(RoleError::from(arena())))),
        ("bench link", Box::new(BenchError::from(LinkError::Transport(transport())))),
        ("bench io", Box::new(BenchError::from(io("bench io cause")))),
    ]
}

#[test]
fn every_cause_is_named_once_in_the_chain() {
    let mut repeats = Vec::new();
    for (name, e) in errors() {
        // anyhow's `{:#}` prints each error of the chain, joined by ": ".
        let mut texts = vec![e.to_string()];
        let mut at: &dyn Error = e.as_ref();
        while let Some(s) = at.source() {
            texts.push(s.to_string());
            at = s;
        }
        for w in texts.windows(2) {
            if w[0].contains(&w[1]) {
                repeats.push(format!("{name}: {:?} already says its source {:?}", w[0], w[1]));
            }
        }
        let shown = format!("{:#}", anyhow::Error::from_boxed(e));
        // The innermost cause is in the text, once.
        let cause = texts.last().unwrap();
        let innermost = cause.rsplit(": ").next().unwrap();
        assert_eq!(shown.matches(innermost).count(), 1, "{name}: {shown:?}");
    }
    assert!(repeats.is_empty(), "causes named twice: {repeats:#?}");
}
