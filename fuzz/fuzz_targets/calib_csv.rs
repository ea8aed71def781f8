//! Calibration data files as `fit` reads them: the project's CSV layout and the dVRK 2017 clamp
//! and torque-offset layouts. The first input byte picks the `--joint` value (none, 1, 2 or the
//! invalid 3), whether the file is also given as the torque-offset sweep, the model and the
//! `--split` reading; the rest is the file. Rows that parse must come back unchanged through the project-layout writer, and the
//! whole fit (`fit_cmd::compute`, which validates what it would write) must not panic.
#![no_main]

#[path = "common.rs"]
mod common;

use dvrk_sidecar::calib::data::{read_rows, write_rows};
use dvrk_sidecar::calib::fit_cmd::{FitArgs, ModelArg, SplitArg, compute};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, csv)) = data.split_first() else {
        return;
    };
    let joint = [None, Some(1u8), Some(2), Some(3)][usize::from(sel & 3)];
    let also_sweep = sel & 4 != 0;
    let path = common::scratch_file("calib.csv", csv);
    let Ok((_, rows)) = read_rows(&path, joint) else {
        return;
    };
    assert!(!rows.is_empty());
    assert!(rows.iter().all(|r| r.joint == 1 || r.joint == 2));
    let mut out = Vec::new();
    write_rows(&mut out, &rows).expect("writing to memory");
    let back_path = common::scratch_file("calib-back.csv", &out);
    let (_, back) = read_rows(&back_path, None).expect("the written file reads back");
    assert_eq!(back, rows, "round trip through the project layout");

    let args = FitArgs {
        add: false,
        clamp: vec![path.clone()],
        torque_offset: if also_sweep { vec![path] } else { vec![] },
        joint: joint.into_iter().collect(),
        out: common::scratch_dir().join("never-written.toml"),
        plots: None,
        json: false,
        model: if sel & 8 != 0 {
            ModelArg::Continuous
        } else {
            ModelArg::Paper
        },
        tau_min_nm: vec![0.1, 0.2],
        font: common::scratch_dir().join("no-font.ttf"),
        dynamics: None,
        gate_sigmas: 4.0,
        split: [
            SplitArg::Auto,
            SplitArg::Motion,
            SplitArg::Load,
            SplitArg::LoadFriction,
        ][usize::from((sel >> 4) & 3)],
    };
    let _ = compute(&args);
});
