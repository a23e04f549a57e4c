//! The documentation stays true to the code: the configuration reference
//! (`docs/config.md`) names every key of the config with its default, and
//! only those; the README is short, and its commands, config paths,
//! Gymnasium IDs and links exist.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::process::Command;

use rotorhive_roles::config::{Config, Curriculum};
use rotorhive_sim::{GenParams, Goal, MapEncoding, MapSpec, TrackSpec};

mod common;
use common::root;

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// `key -> default cell` of every row of the reference's tables.
fn reference() -> BTreeMap<String, String> {
    let mut rows = BTreeMap::new();
    for line in read("docs/config.md").lines().filter(|l| l.starts_with("| `")) {
        let cells: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
        assert!(cells.len() >= 4, "a row of docs/config.md without its four cells: {line}");
        let key = cells[0].trim_matches('`').to_string();
        assert!(
            rows.insert(key.clone(), cells[1].to_string()).is_none(),
            "`{key}` twice in docs/config.md"
        );
    }
    rows
}

fn flatten(prefix: &str, value: &toml::Value, out: &mut BTreeMap<String, toml::Value>) {
    match value {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                flatten(&key, v, out);
            }
        }
        v => {
            out.insert(prefix.to_string(), v.clone());
        }
    }
}

/// Every key of the config with the value it takes when left out: the
/// defaults, with each optional section present at its own defaults.
fn code_keys() -> BTreeMap<String, toml::Value> {
    let mut cfg = Config::default();
    cfg.sim.generator = Some(GenParams::default());
    // The curriculum's required keys given, `stages` from serde's default.
    cfg.sim.curriculum = Some(
        toml::from_str::<Curriculum>("key = \"spacing\"\nfrom = 6.0\nover_env_steps = 1").unwrap(),
    );
    // A goal that is on is written out; `enabled` itself is off by default.
    cfg.sim.goal = Goal { enabled: true, ..Goal::default() };
    // So is a camera map that is on; its encoding is `none` by default.
    cfg.sim.map = MapSpec { encoding: MapEncoding::Rays, ..MapSpec::default() };
    // And seen movers; off (`count` 0) by default.
    cfg.sim.tracks = TrackSpec { count: 5, ..TrackSpec::default() };
    // And a camera with every key given (each optional: the preset's).
    cfg.sim.camera = rotorhive_roles::config::camera::CameraSection {
        preset: Some(rotorhive_roles::config::camera::CameraPreset::Paper),
        width: Some(32),
        height: Some(32),
        hfov_deg: Some(90.0),
        range: Some(20.0),
        pool: Some(1),
    };
    cfg.sim.depth_range = Some(20.0);
    let mut out = BTreeMap::new();
    flatten("", &toml::Value::try_from(&cfg).unwrap(), &mut out);
    out.insert("sim.goal.enabled".into(), toml::Value::Boolean(Goal::default().enabled));
    out.insert("sim.map.encoding".into(), toml::Value::String("none".into()));
    out.insert("sim.tracks.count".into(), toml::Value::Integer(0));
    out
}

fn same(a: &toml::Value, b: &toml::Value) -> bool {
    use toml::Value::{Array, Float, Integer};
    let num = |v: &toml::Value| match v {
        Integer(i) => Some(*i as f64),
        Float(f) => Some(*f),
        _ => None,
    };
    match (a, b) {
        (Integer(x), Integer(y)) => x == y,
        (Array(x), Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same(x, y)),
        _ => match (num(a), num(b)) {
            (Some(x), Some(y)) => (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1.0),
            _ => a == b,
        },
    }
}

#[test]
fn the_config_reference_names_every_key_and_its_default() {
    let doc = reference();
    let code = code_keys();
    let in_code: BTreeSet<&String> = code.keys().collect();
    let in_doc: BTreeSet<&String> = doc.keys().collect();
    let undocumented: Vec<_> = in_code.difference(&in_doc).collect();
    let unknown: Vec<_> = in_doc.difference(&in_code).collect();
    assert!(undocumented.is_empty(), "config keys missing from docs/config.md: {undocumented:?}");
    assert!(unknown.is_empty(), "docs/config.md names keys the config does not have: {unknown:?}");
    assert!(code.len() > 100, "only {} keys found: the flattening is broken", code.len());
    let required = ["sim.curriculum.key", "sim.curriculum.from", "sim.curriculum.over_env_steps"];
    for (key, cell) in &doc {
        if required.contains(&key.as_str()) {
            assert_eq!(cell, "required", "`{key}` has no default");
            continue;
        }
        let literal = cell.strip_prefix('`').and_then(|c| c.strip_suffix('`'));
        let literal =
            literal.unwrap_or_else(|| panic!("`{key}`: the default {cell} is not a `literal`"));
        let parsed: toml::Table = toml::from_str(&format!("v = {literal}"))
            .unwrap_or_else(|e| panic!("`{key}`: the default {literal} is not TOML: {e}"));
        assert!(
            same(&parsed["v"], &code[key]),
            "`{key}`: docs/config.md says {literal}, the code {}",
            code[key]
        );
    }
}

/// Markdown files of the README and the guide.
fn markdown() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md"), root().join("ARCHITECTURE.md")];
    for dir in ["docs", "docs/results"] {
        for entry in std::fs::read_dir(root().join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "md") {
                files.push(path);
            }
        }
    }
    files
}

/// Tokens of `text` that start with `start`, up to the first character
/// that no path holds.
fn tokens<'a>(text: &'a str, start: &str) -> Vec<&'a str> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find(start) {
        let tail = &rest[i..];
        let end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || "/._-".contains(c)))
            .unwrap_or(tail.len());
        out.push(tail[..end].trim_end_matches('.'));
        rest = &tail[end..];
    }
    out
}

#[test]
fn the_readme_is_short_and_every_link_and_path_of_the_docs_exists() {
    let readme = read("README.md");
    let lines = readme.lines().count();
    assert!(lines <= 350, "README.md has {lines} lines (at most 350: the rest goes under docs/)");
    let mut broken = Vec::new();
    for file in markdown() {
        let text = std::fs::read_to_string(&file).unwrap();
        let dir = file.parent().unwrap();
        for part in text.split("](").skip(1) {
            let target = &part[..part.find(')').unwrap_or(part.len())];
            let target = target.split('#').next().unwrap();
            if !target.is_empty() && !target.contains("://") && !dir.join(target).exists() {
                broken.push(format!("{}: link {target}", file.display()));
            }
        }
        // Config and arena paths (placeholders in capitals aside).
        for path in tokens(&text, "configs/") {
            let placeholder = path.chars().any(|c| c.is_ascii_uppercase());
            if path.ends_with(".toml") && !placeholder && !root().join(path).exists() {
                broken.push(format!("{}: {path}", file.display()));
            }
        }
    }
    assert!(broken.is_empty(), "links and paths of the docs that do not exist: {broken:#?}");
}

#[test]
fn the_readme_names_only_gymnasium_ids_that_are_registered() {
    let init = read("crates/py/python/rotorhive/__init__.py");
    let mut ids: BTreeSet<String> =
        rotorhive_roles::levels::LEVELS.iter().map(|l| l.1.to_string()).collect();
    ids.extend(tokens(&init, "rotorhive/").into_iter().map(str::to_string));
    let readme = read("README.md");
    let named: Vec<&str> =
        tokens(&readme, "rotorhive/").into_iter().filter(|t| t.ends_with("-v0")).collect();
    assert!(named.len() >= 6, "{named:?}");
    for id in named {
        assert!(
            ids.contains(id),
            "README.md names {id}, which the package does not register ({ids:?})"
        );
    }
}

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_hive")).args(args).arg("--help").output().unwrap();
    assert!(out.status.success(), "hive {args:?} --help failed");
    String::from_utf8(out.stdout).unwrap()
}

/// The subcommand of a command line after `hive` (`train`, or `bench
/// seeds`; `--domain NAME` skipped) and its `--options`.
fn command(line: &str) -> (Vec<&str>, Vec<&str>) {
    let mut words: Vec<&str> = line.split_whitespace().skip(1).collect();
    if words.first() == Some(&"--domain") {
        words.drain(..2);
    }
    let n = if words.first() == Some(&"bench") { 2 } else { 1 };
    let options =
        words[n..].iter().filter(|w| w.starts_with("--")).map(|w| w.split('=').next().unwrap());
    (words[..n].to_vec(), options.collect())
}

#[test]
fn every_hive_command_of_the_readme_exists_with_its_options() {
    let readme = read("README.md");
    let mut checked = 0;
    let mut wrong = Vec::new();
    // Command lines of its code blocks, continuation lines joined.
    let joined = readme.replace("\\\n", " ");
    for line in joined.lines().filter(|l| l.starts_with("target/release/hive ")) {
        let (sub, options) = command(line);
        let text = help(&sub);
        for option in options {
            if !text.contains(option) {
                wrong.push(format!("`hive {}` has no {option}", sub.join(" ")));
            }
        }
        checked += 1;
    }
    assert!(checked >= 10, "only {checked} command lines found in README.md");
    // The commands table: every command its first column names, the later
    // names of a cell (`hive bench sim`, `render`, ...) under the first one's
    // parent.
    let (top, bench) = (help(&[]), help(&["bench"]));
    let listed =
        |help: &str, w: &str| help.lines().any(|l| l.trim_start().starts_with(&format!("{w} ")));
    for row in readme.lines().filter(|l| l.starts_with("| `hive ")) {
        let mut names = row.split('|').nth(1).unwrap().split('`').skip(1).step_by(2);
        let first: Vec<&str> = names.next().unwrap().split_whitespace().collect();
        let (parent, help, sub) =
            if first[1] == "bench" { ("bench ", &bench, first[2]) } else { ("", &top, first[1]) };
        for word in std::iter::once(sub).chain(names) {
            if !listed(help, word) {
                wrong.push(format!("no `hive {parent}{word}`"));
            }
        }
    }
    assert!(wrong.is_empty(), "README.md's commands that hive does not have: {wrong:#?}");
}
