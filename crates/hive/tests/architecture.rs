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
