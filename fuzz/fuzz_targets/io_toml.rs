//! This project's actuator conversion file (config/io/*.toml) as `serve` loads it: parse,
//! validate (`IoConfig::from_params`), then set an instrument's coupling as the service config
//! does. A valid config must survive the round trip through its own TOML form unchanged.
#![no_main]

use dvrk_sidecar::formats::io_from_toml;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = io_from_toml(text) else {
        return;
    };
    let emitted = toml::to_string(&cfg.to_params()).expect("a valid IoConfig serialises");
    let back = io_from_toml(&emitted)
        .unwrap_or_else(|e| panic!("re-reading the emitted file fails: {e:#}\n{emitted}"));
    assert_eq!(
        back, cfg,
        "round trip through TOML changes the config:\n{emitted}"
    );

    let mut coupled = cfg.clone();
    let lnd = dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006").expect("in the catalog");
    if let Some(c) = lnd.actuator_to_joint_position {
        coupled
            .set_coupling(c)
            .expect("the catalog's coupling is invertible");
    }
});
