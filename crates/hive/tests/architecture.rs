//! ARCHITECTURE.md's code map names every crate of the workspace.

use std::path::PathBuf;

#[test]
fn every_crate_is_in_the_code_map() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let mut n = 0;
    for entry in std::fs::read_dir(root.join("crates")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        assert!(doc.contains(&format!("### `crates/{name}`")), "crates/{name} is missing from ARCHITECTURE.md's code map");
        n += 1;
    }
    assert!(n >= 6);
}

/// A dependency: its package name and the features asked of it.
type Dependency = (String, Vec<String>);

/// The workspace's crates and their direct dependencies (by package name,
/// with the features asked of each), from `cargo metadata`.
fn dependencies() -> Vec<(String, Vec<Dependency>)> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out =
        std::process::Command::new(env!("CARGO")).current_dir(&root).args(["metadata", "--format-version", "1", "--no-deps", "--offline"]).output().unwrap();
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["kind"].is_null())
                .map(|d| (d["name"].as_str().unwrap().to_string(), d["features"].as_array().unwrap().iter().map(|f| f.as_str().unwrap().to_string()).collect()))
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

/// Architecture Invariant: the domain crates (sim, model, replay) never
/// depend on the transport, iceoryx2 or zenoh; the transport never depends
/// on candle or rapier.
#[test]
fn domain_crates_stay_pure_and_the_transport_knows_no_domain() {
    let deps = dependencies();
    assert!(deps.len() >= 7, "{deps:?}");
    let uses = |krate: &str, what: &[&str]| -> Vec<String> {
        let (_, d) = deps.iter().find(|(n, _)| n == krate).unwrap_or_else(|| panic!("no crate {krate}"));
        d.iter().filter(|(n, _)| what.iter().any(|w| n.starts_with(w))).map(|(n, _)| n.clone()).collect()
    };
    for domain in ["rotorhive-sim", "rotorhive-model", "rotorhive-replay"] {
        let bad = uses(domain, &["iceoryx2", "zenoh", "rotorhive-transport", "rotorhive-roles"]);
        assert!(bad.is_empty(), "{domain} depends on {bad:?}");
    }
    let bad = uses("rotorhive-transport", &["candle", "rapier", "rotorhive-sim", "rotorhive-model"]);
    assert!(bad.is_empty(), "rotorhive-transport depends on {bad:?}");
    // Zenoh stays in the link crate; the link knows no model, simulator or role.
    for (krate, d) in &deps {
        if krate != "rotorhive-link" {
            assert!(!d.iter().any(|(n, _)| n == "zenoh"), "{krate} imports zenoh: only rotorhive-link may");
        }
    }
    let bad = uses("rotorhive-link", &["candle", "rapier", "rotorhive-sim", "rotorhive-model", "rotorhive-roles"]);
    assert!(bad.is_empty(), "rotorhive-link depends on {bad:?}");
    let zenoh = deps.iter().find(|(n, _)| n == "rotorhive-link").and_then(|(_, d)| d.iter().find(|(n, _)| n == "zenoh")).expect("the link imports zenoh");
    assert_eq!(zenoh.1, vec!["transport_tcp".to_string()], "zenoh with its TCP transport only");
    // Python stays in the Python package's crate.
    for (krate, d) in &deps {
        if krate != "rotorhive-py" {
            let py: Vec<&String> = d.iter().map(|(n, _)| n).filter(|n| *n == "pyo3" || *n == "numpy").collect();
            assert!(py.is_empty(), "{krate} imports {py:?}: only rotorhive-py may");
        }
    }
    // Only the binary parses command lines: the roles take a context.
    let bad = uses("rotorhive-roles", &["clap"]);
    assert!(bad.is_empty(), "rotorhive-roles depends on {bad:?}");
}
