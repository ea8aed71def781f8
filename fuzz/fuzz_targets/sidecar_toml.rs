//! The service configuration (sidecar.toml) as `serve` and `check-config` load it
//! (`SidecarConfig::load`): parse, check every field, then load and validate the files it
//! names. The input is written to a scratch directory beside links to the repository's own
//! config files (io/, compliance/, sim/, data/ = tests/data/io, bad/ = tests/data/bad-config), so that the relative
//! paths of real configs resolve to real files. Inputs naming an absolute path or `..` are only
//! parsed: the loader would read whatever file they name.
#![no_main]

#[path = "common.rs"]
mod common;

use std::path::{Component, Path};
use std::sync::Once;

use dvrk_sidecar::config::{SidecarConfig, SidecarParams, Source};
use libfuzzer_sys::fuzz_target;

fn confined(p: &Path) -> bool {
    p.components().all(|c| matches!(c, Component::Normal(_)))
}

fuzz_target!(|data: &[u8]| {
    static LINKS: Once = Once::new();
    LINKS.call_once(|| {
        let repo = common::repo();
        for (link, target) in [
            ("io", repo.join("config/io")),
            ("compliance", repo.join("config/compliance")),
            ("sim", repo.join("config/sim")),
            ("data", repo.join("tests/data/io")),
            ("bad", repo.join("tests/data/bad-config")),
        ] {
            let l = common::scratch_dir().join(link);
            if !l.exists() {
                std::os::unix::fs::symlink(target, &l).expect("linking the config directories");
            }
        }
    });
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(p) = toml::from_str::<SidecarParams>(text) {
        let scenario = p.sim.as_ref().map(|s| s.scenario.as_path());
        if !(confined(&p.io) && confined(&p.compliance) && scenario.is_none_or(confined)) {
            return;
        }
    }
    let path = common::scratch_file("sidecar.toml", data);
    let Ok(cfg) = SidecarConfig::load(&path) else {
        return;
    };
    let again = Source::parse(&cfg.source.to_string()).expect("a parsed source prints back");
    assert_eq!(again, cfg.source);
    assert_eq!(cfg.scenario.is_some(), cfg.source == Source::Sim);
});
