//! The service configuration (sidecar.toml) as `serve` and `check-config` load it
//! (`ServiceConfig::load`, one arm or several `[[arm]]`): parse, check every field, then load and validate the files it
//! names. The input is written to a scratch directory beside links to the repository's own
//! config files (io/, compliance/, sim/, data/ = tests/data/io, bad/ = tests/data/bad-config), so that the relative
//! paths of real configs resolve to real files. Inputs naming an absolute path or `..` are only
//! parsed: the loader would read whatever file they name.
#![no_main]

#[path = "common.rs"]
mod common;

use std::path::{Component, Path};
use std::sync::Once;

use dvrk_sidecar::config::{ServiceConfig, SidecarParams, Source};
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
    // A several-arm file names its files in each [[arm]]: the same confinement.
    if let Ok(t) = toml::from_str::<toml::Table>(text)
        && let Some(arms) = t.get("arm").and_then(|a| a.as_array())
    {
        let paths = arms.iter().filter_map(|a| a.as_table()).flat_map(|a| {
            ["io", "compliance", "scenario"]
                .into_iter()
                .filter_map(|k| a.get(k).and_then(|v| v.as_str()).map(str::to_owned))
        });
        let base = t
            .get("base_frame")
            .and_then(|b| b.get("dvrk_json"))
            .and_then(|v| v.as_str())
            .map(str::to_owned);
        if !paths.chain(base).all(|q| confined(Path::new(&q))) {
            return;
        }
        if arms.iter().any(|a| a.get("base_frame").is_some()) {
            return;
        }
    }
    let path = common::scratch_file("sidecar.toml", data);
    let Ok(svc) = ServiceConfig::load(&path) else {
        return;
    };
    assert!(!svc.arms.is_empty());
    for cfg in &svc.arms {
        let again = Source::parse(&cfg.source.to_string()).expect("a parsed source prints back");
        assert_eq!(again, cfg.source);
        assert_eq!(cfg.scenario.is_some(), cfg.source == Source::Sim);
        assert_eq!(cfg.source, svc.arms[0].source, "every arm shares the source");
    }
});
