#!/usr/bin/env python3
"""Non-test Rust lines per crate (the issue's 'hive holds at most 25 %').

Counts every line of each crate's `src/` except files named `tests.rs` and
everything from a top-level `#[cfg(test)]` on (test modules sit at the end of
their file in this workspace). Usage: scripts/line_shares.py [--check PCT]
"""
import pathlib, sys

root = pathlib.Path(__file__).resolve().parent.parent
counts = {}
for cargo in sorted(root.glob("*/*/Cargo.toml")) + sorted(root.glob("benches/Cargo.toml")):
    crate = cargo.parent
    if "target" in crate.parts:
        continue
    n = 0
    for f in sorted((crate / "src").rglob("*.rs")):
        if f.name == "tests.rs":
            continue
        for line in f.read_text().splitlines():
            if line.startswith("#[cfg(test)]"):
                break
            n += 1
    if n:
        counts[str(crate.relative_to(root))] = n
total = sum(counts.values())
for k, v in sorted(counts.items(), key=lambda kv: -kv[1]):
    print(f"{k:24} {v:6} {100 * v / total:5.1f} %")
print(f"{'total':24} {total:6}")
if len(sys.argv) > 2 and sys.argv[1] == "--check":
    share = 100 * counts.get("crates/hive", 0) / total
    if share > float(sys.argv[2]):
        sys.exit(f"crates/hive holds {share:.1f} % of the non-test lines (limit {sys.argv[2]} %)")
