//! The dVRK's own sawRobotIO1394 JSON (version 6, comments allowed) as `serve` imports it:
//! comment stripping, JSON parsing, import and validation. An imported config must convert to
//! this project's TOML schema and validate again to the same config.
#![no_main]

use dvrk_io::IoConfig;
use dvrk_sidecar::formats::io_from_saw_json;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = io_from_saw_json(text) else {
        return;
    };
    let again = IoConfig::from_params(cfg.to_params())
        .unwrap_or_else(|e| panic!("an imported config fails its own validation: {e}"));
    assert_eq!(again, cfg);
    let emitted = toml::to_string(&cfg.to_params()).expect("a valid IoConfig serialises");
    let back = dvrk_sidecar::formats::io_from_toml(&emitted)
        .unwrap_or_else(|e| panic!("the imported config written as TOML fails: {e:#}\n{emitted}"));
    assert_eq!(back, cfg);
});
