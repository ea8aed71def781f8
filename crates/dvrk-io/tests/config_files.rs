//! Every shipped config/io/*.toml parses; every tests/data/io/bad/*.toml fails with the error its
//! first line names (`# expect: <text>`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;

fn toml_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

#[test]
fn shipped_io_configs_parse() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/io");
    let files = toml_files(&dir);
    assert!(!files.is_empty());
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        common::io_from_toml(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
    }
}

#[test]
fn bad_io_configs_fail_with_their_expected_error() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/io/bad");
    let files = toml_files(&dir);
    assert!(files.len() >= 10);
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        let expect = text
            .lines()
            .next()
            .and_then(|l| l.strip_prefix("# expect: "))
            .unwrap_or_else(|| panic!("{}: no expect line", f.display()));
        match common::io_from_toml(&text) {
            Ok(_) => panic!(
                "{} parsed, expected error containing {expect:?}",
                f.display()
            ),
            Err(e) => assert!(
                e.to_string().contains(expect),
                "{}: error {e:?} does not contain {expect:?}",
                f.display()
            ),
        }
    }
}

#[test]
fn saw_json_sample_imports() {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/io/sawRobotIO1394-PSM1-00000.json"),
    )
    .unwrap();
    let c = common::io_from_saw_json(&text).unwrap();
    assert_eq!(c.board_ids(), &[6, 7]);
}
