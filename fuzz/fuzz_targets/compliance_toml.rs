//! A compliance parameter file (config/compliance/*.toml) as `serve` loads it: parse and
//! validate. A valid file must round-trip through the fitter's emitter (`to_toml_string`), and
//! correcting a physically possible sample with it must give finite joint values.
#![no_main]

use dvrk_compliance::INSERTION_LIMITS_M;
use dvrk_sidecar::formats::compliance_from_toml;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = compliance_from_toml(text) else {
        return;
    };
    let emitted = cfg.to_params().to_toml_string();
    let back = compliance_from_toml(&emitted)
        .unwrap_or_else(|e| panic!("re-reading the emitted file fails: {e:#}\n{emitted}"));
    assert_eq!(back, cfg, "round trip changes the parameters:\n{emitted}");

    let [lo, hi] = INSERTION_LIMITS_M;
    for insertion_m in [lo, 0.5 * (lo + hi), hi] {
        for q in [-1.0, 0.0, 0.7] {
            for tau in [-5.0, -0.05, 0.0, 0.3, 5.0] {
                let c = cfg.correct(&[q, q, insertion_m], &[tau, -tau, 1.0]);
                assert!(
                    c.position.iter().chain(&c.delta_rad).all(|v| v.is_finite()),
                    "q = {q} rad, L = {insertion_m} m, tau = {tau} N·m gives {c:?}"
                );
            }
        }
    }
});
