//! Fixtures shared by the dvrk-sim integration tests: the repository's config files.
#![allow(dead_code)]

use std::path::Path;

use dvrk_io::IoConfig;
use dvrk_sim::Scenario;

pub const NS_PER_MS: u64 = 1_000_000;

pub fn repo() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

/// config/io/psm-classic.toml, the conversions the emulated boards encode with (parsed once).
pub fn io_config() -> IoConfig {
    static IO: std::sync::OnceLock<IoConfig> = std::sync::OnceLock::new();
    IO.get_or_init(|| {
        let text = std::fs::read_to_string(repo().join("config/io/psm-classic.toml")).unwrap();
        IoConfig::from_params(toml::from_str(&text).unwrap()).unwrap()
    })
    .clone()
}

/// A scenario of config/sim/.
pub fn scenario(name: &str) -> Scenario {
    scenario_from_toml(&std::fs::read_to_string(repo().join("config/sim").join(name)).unwrap())
}

/// A scenario from TOML text: parsed here (the application's job), validated by the crate.
pub fn scenario_from_toml(text: &str) -> Scenario {
    Scenario::from_params(toml::from_str(text).unwrap()).unwrap()
}
