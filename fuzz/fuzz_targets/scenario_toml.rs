//! A simulator scenario (config/sim/*.toml) as `serve` and `sim` load it: parse and validate,
//! then build the arm and run the first steps of its motion. A valid scenario must not drive the
//! simulated joints to non-finite values.
#![no_main]

use dvrk_sidecar::formats::scenario_from_toml;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(sc) = scenario_from_toml(text) else {
        return;
    };
    let mut psm = sc.build_psm();
    let driver = sc.motion_driver();
    for i in 0..20 {
        driver.apply(i as f64 * sc.dt_s, &mut psm);
        psm.step(sc.dt_s);
    }
    let s = psm.joint_state();
    assert!(
        s.position
            .iter()
            .chain(&s.velocity)
            .chain(&s.effort)
            .all(|v| v.is_finite()),
        "a valid scenario gives {s:?} after 20 steps"
    );
});
