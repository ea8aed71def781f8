//! Shared by the targets (each includes it with `#[path]`): the layouts every firmware revision
//! and board kind has, the repository's own config files as real inputs, and a scratch file for
//! the parsers that read paths.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use dvrk_io::IoConfig;
use dvrk_io::convert::IoParams;
use dvrk_io::wire::{BlockLayout, BoardKind};

/// Every (firmware, board kind) with a feedback-block layout (reference §2.1): Rev 7 QLA only,
/// Rev 8 and 9 all three kinds.
pub const LAYOUTS: [(u32, BoardKind); 7] = [
    (7, BoardKind::Qla),
    (8, BoardKind::Qla),
    (8, BoardKind::Dqla),
    (8, BoardKind::Drac),
    (9, BoardKind::Qla),
    (9, BoardKind::Dqla),
    (9, BoardKind::Drac),
];

/// The layout picked by a selector byte of the input.
pub fn layout(selector: u8) -> BlockLayout {
    let (fw, kind) = LAYOUTS[usize::from(selector) % LAYOUTS.len()];
    BlockLayout::new(fw, kind).expect("every entry of LAYOUTS has a layout")
}

/// The repository root (fuzz/..), where config/ lives.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// config/io/psm-classic.toml, parsed once.
pub fn classic_params() -> &'static IoParams {
    static P: OnceLock<IoParams> = OnceLock::new();
    P.get_or_init(|| {
        let text = std::fs::read_to_string(repo().join("config/io/psm-classic.toml"))
            .expect("config/io/psm-classic.toml");
        toml::from_str(&text).expect("config/io/psm-classic.toml parses")
    })
}

/// A real conversion config for `kind`: the repository's Classic PSM1 file for QLA1 (boards 6
/// and 7), and the same actuators on one DQLA or dRAC board (board 6, axes 0..6) for the others.
pub fn io_config(kind: BoardKind) -> &'static IoConfig {
    static C: OnceLock<[IoConfig; 3]> = OnceLock::new();
    let all = C.get_or_init(|| {
        [BoardKind::Qla, BoardKind::Dqla, BoardKind::Drac].map(|k| {
            let mut p = classic_params().clone();
            p.hardware_version = k.name().to_owned();
            if k != BoardKind::Qla {
                for (i, a) in p.actuators.iter_mut().enumerate() {
                    a.board_id = 6;
                    a.axis_id = i as u8;
                }
            }
            IoConfig::from_params(p).expect("the derived IO config is valid")
        })
    });
    match kind {
        BoardKind::Qla => &all[0],
        BoardKind::Dqla => &all[1],
        BoardKind::Drac => &all[2],
    }
}

/// A per-process scratch directory under the system temp dir (for parsers that read files).
pub fn scratch_dir() -> &'static Path {
    static D: OnceLock<PathBuf> = OnceLock::new();
    D.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("dvrk-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("creating the scratch directory");
        d
    })
}

/// Writes `data` to `name` in the scratch directory and returns its path.
pub fn scratch_file(name: &str, data: &[u8]) -> PathBuf {
    let p = scratch_dir().join(name);
    std::fs::write(&p, data).expect("writing the scratch file");
    p
}
