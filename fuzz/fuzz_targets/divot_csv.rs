//! Divot-push data files as `evaluate --data` reads them (with or without the simulator's truth
//! columns). Rows that parse must come back unchanged through the writer, and the evaluation with
//! the repository's compliance parameters and the Classic PSM's kinematics must not panic.
#![no_main]

#[path = "common.rs"]
mod common;

use std::sync::OnceLock;

use dvrk_compliance::{ArmKind, ComplianceConfig, PsmKinematics};
use dvrk_sidecar::calib::data::{read_divot, write_divot};
use dvrk_sidecar::calib::evaluate::evaluate;
use libfuzzer_sys::fuzz_target;

fn setup() -> &'static (ComplianceConfig, PsmKinematics) {
    static S: OnceLock<(ComplianceConfig, PsmKinematics)> = OnceLock::new();
    S.get_or_init(|| {
        let cfg = dvrk_sidecar::config::load_compliance(
            &common::repo().join("config/compliance/sim-psm.toml"),
        )
        .expect("config/compliance/sim-psm.toml loads");
        let lnd = dvrk_compliance::instrument("LARGE_NEEDLE_DRIVER_400006").expect("in catalog");
        (cfg, PsmKinematics::new(ArmKind::Classic, lnd))
    })
}

fuzz_target!(|data: &[u8]| {
    let path = common::scratch_file("divot.csv", data);
    let Ok(rows) = read_divot(&path) else {
        return;
    };
    let mut out = Vec::new();
    write_divot(&mut out, &rows).expect("writing to memory");
    let back_path = common::scratch_file("divot-back.csv", &out);
    let back = read_divot(&back_path).expect("the written file reads back");
    assert_eq!(back, rows, "round trip through the writer");
    let (cfg, fk) = setup();
    let _ = evaluate(cfg, fk, &rows);
});
