//! ARCHITECTURE.md's code map names every crate of the workspace.

use std::path::{Path, PathBuf};

#[test]
fn every_crate_is_in_the_code_map() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    // A map, not a second copy of the code: a few lines per crate.
    let lines = doc.lines().count();
    assert!(lines <= 400, "ARCHITECTURE.md has {lines} lines (at most 400)");
    let mut n = 0;
    for entry in std::fs::read_dir(root.join("crates")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        assert!(
            doc.contains(&format!("### `crates/{name}`")),
            "crates/{name} is missing from ARCHITECTURE.md's code map"
        );
        n += 1;
    }
    assert!(n >= 8);
    assert!(doc.contains("### `benches`"), "benches is missing from ARCHITECTURE.md's code map");
    // And every module of every crate (`sumtree.rs` or `sumtree`), so that
    // a new file cannot hide from the map.
    let mut missing = Vec::new();
    for dir in source_dirs() {
        for f in sources(&dir) {
            let stem = f.file_stem().unwrap().to_string_lossy().into_owned();
            if !["lib", "main", "mod"].contains(&stem.as_str())
                && !doc.contains(&format!("{stem}.rs"))
                && !doc.contains(&format!("`{stem}`"))
            {
                missing.push(f.display().to_string());
            }
        }
    }
    assert!(missing.is_empty(), "modules missing from ARCHITECTURE.md's code map: {missing:?}");
}

/// Rust source files under `dir`, recursively.
fn sources(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(sources(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out
}

/// The source folders of the workspace: every crate's `src` and the
/// benches'.
fn source_dirs() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root.join("crates"))
        .unwrap()
        .map(|e| e.unwrap().path().join("src"))
        .collect();
    dirs.push(root.join("benches/src"));
    dirs
}

/// The folders of examples and tests: every crate's `examples` and `tests`,
/// the benches' examples and the end-to-end `tests/`.
fn example_and_test_dirs() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut dirs = Vec::new();
    for entry in std::fs::read_dir(root.join("crates")).unwrap() {
        let krate = entry.unwrap().path();
        dirs.extend([krate.join("examples"), krate.join("tests")]);
    }
    dirs.extend(["benches/examples", "tests"].map(|d| root.join(d)));
    dirs.retain(|d| d.exists());
    dirs
}

/// A file's lines before its test module (`#[cfg(test)]` at the top level;
/// test modules sit at the end of their file here); none for `tests.rs`.
fn non_test_lines(path: &Path) -> Vec<String> {
    if path.file_name().is_some_and(|n| n == "tests.rs") {
        return Vec::new();
    }
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .take_while(|l| !l.starts_with("#[cfg(test)]"))
        .map(str::to_string)
        .collect()
}

/// Architecture Invariant: the binary is a thin layer: `crates/hive` holds
/// at most a quarter of the workspace's non-test Rust lines.
#[test]
fn the_binary_holds_at_most_a_quarter_of_the_code() {
    let dirs = source_dirs();
    let (mut total, mut hive) = (0, 0);
    for dir in dirs.iter().filter(|d| d.exists()) {
        let n: usize = sources(dir).iter().map(|f| non_test_lines(f).len()).sum();
        total += n;
        if dir.ends_with("crates/hive/src") {
            hive = n;
        }
    }
    assert!(hive > 0 && total > 10_000, "{hive} of {total}");
    assert!(
        hive * 4 <= total,
        "crates/hive holds {hive} of {total} non-test lines ({:.1} %), more than 25 %",
        100.0 * hive as f64 / total as f64
    );
}

/// Architecture Invariant: no function of the workspace (every crate's
/// `src`, the benches; tests aside) is longer than 80 lines (from its `fn`
/// line to its closing brace).
#[test]
fn no_function_is_longer_than_80_lines() {
    let mut dirs = source_dirs();
    dirs.extend(example_and_test_dirs().into_iter().filter(|d| !d.ends_with("tests")));
    let files: Vec<PathBuf> = dirs.iter().filter(|d| d.exists()).flat_map(|d| sources(d)).collect();
    assert!(files.len() >= 60, "{files:?}");
    let mut long = Vec::new();
    let mut checked = 0;
    for f in &files {
        let lines = non_test_lines(f);
        for (i, l) in lines.iter().enumerate() {
            let code = l.trim_start();
            let indent = &l[..l.len() - code.len()];
            let is_fn = [
                "fn ",
                "pub fn ",
                "pub(crate) fn ",
                "pub(super) fn ",
                "unsafe fn ",
                "pub unsafe fn ",
                "pub const fn ",
                "const fn ",
                "async fn ",
                "pub async fn ",
            ]
            .iter()
            .any(|p| code.starts_with(p));
            if !is_fn || code.ends_with(';') || code.ends_with('}') {
                continue;
            }
            // A declaration without a body (a trait's required method)
            // whose signature spans lines ends in `;` before any `{`.
            let signature_end = lines[i..].iter().find(|x| x.ends_with('{') || x.ends_with(';'));
            if signature_end.is_some_and(|x| x.ends_with(';')) {
                continue;
            }
            checked += 1;
            let end = lines[i..]
                .iter()
                .position(|x| x == &format!("{indent}}}"))
                .map_or(lines.len() - i, |k| k + 1);
            if end > 80 {
                long.push(format!("{}:{}: {end} lines", f.display(), i + 1));
            }
        }
    }
    assert!(checked > 500, "only {checked} functions found");
    assert!(long.is_empty(), "functions longer than 80 lines: {long:#?}");
}

/// A dependency: its package name and the features asked of it.
type Dependency = (String, Vec<String>);

/// The workspace's crates and their direct dependencies (by package name,
/// with the features asked of each), from `cargo metadata`.
fn dependencies() -> Vec<(String, Vec<Dependency>)> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out = std::process::Command::new(env!("CARGO"))
        .current_dir(&root)
        .args(["metadata", "--format-version", "1", "--no-deps", "--offline"])
        .output()
        .unwrap();
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
                .map(|d| {
                    (
                        d["name"].as_str().unwrap().to_string(),
                        d["features"]
                            .as_array()
                            .unwrap()
                            .iter()
                            .map(|f| f.as_str().unwrap().to_string())
                            .collect(),
                    )
                })
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

/// Architecture Invariant: the domain crates (sim, model, replay, records,
/// config) never depend on the transport, iceoryx2 or zenoh; the transport
/// never depends on candle or rapier; the Python package not on the roles.
#[test]
fn domain_crates_stay_pure_and_the_transport_knows_no_domain() {
    let deps = dependencies();
    assert!(deps.len() >= 7, "{deps:?}");
    let uses = |krate: &str, what: &[&str]| -> Vec<String> {
        let (_, d) =
            deps.iter().find(|(n, _)| n == krate).unwrap_or_else(|| panic!("no crate {krate}"));
        d.iter()
            .filter(|(n, _)| what.iter().any(|w| n.starts_with(w)))
            .map(|(n, _)| n.clone())
            .collect()
    };
    let domains = [
        "rotorhive-sim",
        "rotorhive-model",
        "rotorhive-replay",
        "rotorhive-records",
        "rotorhive-config",
    ];
    for domain in domains {
        let bad = uses(domain, &["iceoryx2", "zenoh", "rotorhive-transport", "rotorhive-roles"]);
        assert!(bad.is_empty(), "{domain} depends on {bad:?}");
        // The layout crate without its iceoryx2 derive.
        let (_, d) = deps.iter().find(|(n, _)| n == domain).unwrap();
        if let Some((_, features)) = d.iter().find(|(n, _)| n == "rotorhive-msg") {
            assert!(
                features.is_empty(),
                "{domain} takes rotorhive-msg with {features:?}: the domain crates use its layout only"
            );
        }
    }
    // The model takes its layout (OBS_LEN, TRANSITION_LEN, …) from msg.
    assert_eq!(uses("rotorhive-model", &["rotorhive-msg"]), vec!["rotorhive-msg".to_string()]);
    let msg = deps.iter().find(|(n, _)| n == "rotorhive-msg").unwrap();
    // Only bytemuck (its headers are Pod) and, for its derive, iceoryx2.
    assert!(
        msg.1.iter().all(|(n, _)| n == "iceoryx2" || n == "bytemuck"),
        "rotorhive-msg depends on {:?}",
        msg.1
    );
    // The records of a run know no candle or rapier either.
    let bad = uses("rotorhive-records", &["candle", "rapier", "rotorhive-model", "rotorhive-sim"]);
    assert!(bad.is_empty(), "rotorhive-records depends on {bad:?}");
    let bad =
        uses("rotorhive-transport", &["candle", "rapier", "rotorhive-sim", "rotorhive-model"]);
    assert!(bad.is_empty(), "rotorhive-transport depends on {bad:?}");
    // Zenoh stays in the link crate; the link knows no model, simulator or role.
    for (krate, d) in &deps {
        if krate != "rotorhive-link" {
            assert!(
                !d.iter().any(|(n, _)| n == "zenoh"),
                "{krate} imports zenoh: only rotorhive-link may"
            );
        }
    }
    let bad = uses(
        "rotorhive-link",
        &["candle", "rapier", "rotorhive-sim", "rotorhive-model", "rotorhive-roles"],
    );
    assert!(bad.is_empty(), "rotorhive-link depends on {bad:?}");
    let zenoh = deps
        .iter()
        .find(|(n, _)| n == "rotorhive-link")
        .and_then(|(_, d)| d.iter().find(|(n, _)| n == "zenoh"))
        .expect("the link imports zenoh");
    let mut features = zenoh.1.clone();
    features.sort();
    assert_eq!(
        features,
        ["transport_quic", "transport_tcp", "transport_tls"].map(String::from).to_vec(),
        "zenoh with its TCP, TLS and QUIC transports only"
    );
    // Python stays in the Python package's crate.
    for (krate, d) in &deps {
        if krate != "rotorhive-py" {
            let py: Vec<&String> =
                d.iter().map(|(n, _)| n).filter(|n| *n == "pyo3" || *n == "numpy").collect();
            assert!(py.is_empty(), "{krate} imports {py:?}: only rotorhive-py may");
        }
    }
    // The Python package reads a config without the roles' transport: with
    // the domain crates above free of it, nothing it links brings iceoryx2.
    let bad = uses("rotorhive-py", &["rotorhive-roles", "rotorhive-transport", "iceoryx2"]);
    assert!(bad.is_empty(), "rotorhive-py depends on {bad:?}");
    // Only the binary parses command lines: the roles take a context.
    let bad = uses("rotorhive-roles", &["clap"]);
    assert!(bad.is_empty(), "rotorhive-roles depends on {bad:?}");
    // Errors by layer: the libraries return their own thiserror types;
    // anyhow is the binary's (and the Python package's, which turns errors
    // into Python exceptions at its edge).
    for (krate, d) in &deps {
        if !["hive", "rotorhive-py"].contains(&krate.as_str()) {
            assert!(
                !d.iter().any(|(n, _)| n == "anyhow"),
                "the library {krate} depends on anyhow: give it a thiserror type"
            );
        }
    }
}

/// A source file's module path inside its crate: `[]` for `lib.rs` and
/// `main.rs`, `["a"]` for `a.rs` and `a/mod.rs`, `["a", "b"]` for `a/b.rs`.
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> =
        rel.iter().map(|p| p.to_string_lossy().trim_end_matches(".rs").to_string()).collect();
    if matches!(parts.last().map(String::as_str), Some("lib" | "main" | "mod")) {
        parts.pop();
    }
    parts
}

/// The paths a line names from its crate (`crate::a::b`, `super::c`,
/// `self::d`), with `use` groups (`crate::{a, b::c}`) spread out; each path
/// as its segments after `crate` (`super` and `self` resolved from the
/// line's `module`).
fn crate_paths(line: &str, module: &[String]) -> Vec<Vec<String>> {
    fn expand(rest: &str, base: Vec<String>, out: &mut Vec<Vec<String>>) {
        let mut path = base;
        let mut chars = rest.trim_start();
        loop {
            if let Some(group) = chars.strip_prefix('{') {
                // Split the group at its top-level commas.
                let (mut depth, mut start) = (0, 0);
                for (i, c) in group.char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' if depth == 0 => {
                            expand(&group[start..i], path.clone(), out);
                            return;
                        }
                        '}' => depth -= 1,
                        ',' if depth == 0 => {
                            expand(&group[start..i], path.clone(), out);
                            start = i + 1;
                        }
                        _ => {}
                    }
                }
                return;
            }
            let end =
                chars.find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(chars.len());
            if end == 0 {
                break;
            }
            path.push(chars[..end].to_string());
            match chars[end..].strip_prefix("::") {
                Some(r) => chars = r,
                None => break,
            }
        }
        out.push(path);
    }
    let mut out = Vec::new();
    let parent = module[..module.len().saturating_sub(1)].to_vec();
    for (key, base) in [("crate::", Vec::new()), ("super::", parent), ("self::", module.to_vec())] {
        let mut at = 0;
        while let Some(i) = line[at..].find(key) {
            let start = at + i;
            at = start + key.len();
            // `rotorhive_crate::` or `my_super::` are other names.
            if line[..start].ends_with(|c: char| c.is_alphanumeric() || c == '_') {
                continue;
            }
            expand(&line[at..], base.clone(), &mut out);
        }
    }
    out
}

/// Architecture Invariant: no two source files of a crate import each other
/// (a `use` or a path through `crate::`, `super::` or `self::`; `mod`
/// declarations and `pub use` re-exports are a module's face, not a
/// dependency), tests aside.
#[test]
fn no_two_source_files_import_each_other() {
    let dirs = source_dirs();
    let mut cycles = Vec::new();
    let mut edges_seen = 0;
    for src in dirs.iter().filter(|d| d.exists()) {
        let files = sources(src);
        let modules: Vec<Vec<String>> = files.iter().map(|f| module_path(src, f)).collect();
        let mut edges = std::collections::BTreeSet::new();
        for (f, m) in files.iter().zip(&modules) {
            for line in non_test_lines(f) {
                let code = line.trim_start();
                if code.starts_with("//")
                    || code.starts_with("pub use ")
                    || code.starts_with("mod ")
                    || code.starts_with("pub mod ")
                {
                    continue;
                }
                for path in crate_paths(code, m) {
                    // The longest prefix that is a module of this crate.
                    let target = (0..=path.len())
                        .rev()
                        .map(|k| &path[..k])
                        .find(|p| modules.iter().any(|m| m.as_slice() == *p))
                        .unwrap_or(&[]);
                    if target != m.as_slice() {
                        edges.insert((m.clone(), target.to_vec()));
                    }
                }
            }
        }
        edges_seen += edges.len();
        for (a, b) in &edges {
            if a < b && edges.contains(&(b.clone(), a.clone())) {
                cycles.push(format!("{}: {} <-> {}", src.display(), a.join("::"), b.join("::")));
            }
        }
    }
    assert!(edges_seen > 100, "only {edges_seen} imports found: the scan is broken");
    assert!(cycles.is_empty(), "source files that import each other: {cycles:#?}");
}

/// Architecture Invariant: `crates/link` stays split by what each part is:
/// no file of it over 400 lines (tests included).
#[test]
fn no_file_of_the_link_is_over_400_lines() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let files = sources(&root.join("crates/link/src"));
    assert!(files.len() >= 8, "{files:?}");
    let long = longer_than(&files, 400);
    assert!(long.is_empty(), "files of crates/link over 400 lines: {long:?}");
}

/// Architecture Invariant: no source file of the workspace is over 800
/// lines, tests and examples included: a file that grows past it is split
/// along its seams (a module's tests go to its `tests.rs`).
#[test]
fn no_source_file_is_over_800_lines() {
    let mut dirs = source_dirs();
    dirs.extend(example_and_test_dirs());
    let files: Vec<PathBuf> = dirs.iter().filter(|d| d.exists()).flat_map(|d| sources(d)).collect();
    assert!(files.len() >= 100, "only {} files found", files.len());
    let long = longer_than(&files, 800);
    assert!(long.is_empty(), "source files over 800 lines: {long:#?}");
}

/// The files of `files` over `limit` lines, each with its count.
fn longer_than(files: &[PathBuf], limit: usize) -> Vec<String> {
    files
        .iter()
        .map(|f| (f, std::fs::read_to_string(f).unwrap().lines().count()))
        .filter(|(_, n)| *n > limit)
        .map(|(f, n)| format!("{}: {n} lines", f.display()))
        .collect()
}
