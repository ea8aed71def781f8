//! The paper's claim, on the simulator: with the tip clamped (or in a divot) and the compliance
//! model set to the simulator's true parameters, the corrected joint positions match the true
//! shaft angles within quantization and noise, and the uncorrected ones do not.
//!
//! Everything goes through the real stack: emulated boards -> dvrk-io EthPort/ArmReader ->
//! dvrk-compliance's `ComplianceConfig::correct`. Also: determinism with a fixed seed.

mod common;

use common::*;
use dvrk_compliance::{
    ComplianceConfig, ComplianceParams, JointParams, ModelKind, TorqueOffsetParams,
};
use dvrk_io::ArmSample;
use dvrk_io::reader::{AccessMode, ArmReader};
use dvrk_sim::emulator::MAX_REPLY_BYTES;
use dvrk_sim::{Emulator, Scenario, SimPort, SimPsm, sim_port};

/// The compliance model with the simulator's true parameters: the shaft's cubic and backlash,
/// the paper's tau_min, and a torque-offset table sampled from the simulator's tau_0.
fn true_model(psm: &SimPsm) -> ComplianceConfig {
    let shaft = psm.params().shaft;
    let tau_min = [0.1, 0.2];
    let joint = (0..2)
        .map(|j| {
            let (lo, hi) = (psm.params().position_min[j], psm.params().position_max[j]);
            let n = 641;
            let position_rad: Vec<f64> = (0..n)
                .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
                .collect();
            let effort_nm = position_rad
                .iter()
                .map(|&q| {
                    let mut qq = [0.0; 7];
                    qq[j] = q;
                    psm.torque_offset(&qq)[j]
                })
                .collect();
            JointParams {
                index: j as i64 + 1,
                backlash_rad: shaft.backlash_rad[j],
                tau_min_nm: tau_min[j],
                inverse_compliance_nm_per_rad: shaft.inverse_compliance_cubic[j],
                insertion_range_m: shaft.insertion_range_m,
                inverse_compliance_rel_sigma: None,
                backlash_rel_sigma: None,
                torque_offset: TorqueOffsetParams {
                    position_rad,
                    effort_nm,
                },
                hysteresis: None,
                dynamics: None,
            }
        })
        .collect();
    ComplianceConfig::from_params(ComplianceParams {
        model: ModelKind::Paper,
        joint,
    })
    .unwrap()
}

struct Rig {
    reader: ArmReader<SimPort>,
    t_ns: u64,
    sample: ArmSample,
}

impl Rig {
    fn new(sc: &Scenario) -> Self {
        let io = io_config();
        let mut port = sim_port(sc, &io).unwrap();
        port.link_mut().advance_to(0);
        Self {
            reader: ArmReader::new(port, io, AccessMode::Exclusive),
            t_ns: 0,
            sample: ArmSample::default(),
        }
    }
    fn emu(&mut self) -> &mut Emulator {
        self.reader.port_mut().link_mut().emulator_mut()
    }
    /// Advance `ms` milliseconds, reading once per millisecond.
    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.t_ns += NS_PER_MS;
            self.reader.port_mut().link_mut().advance_to(self.t_ns);
            self.reader.read(self.t_ns, &mut self.sample).unwrap();
            assert!(self.sample.valid);
        }
    }
    /// Average of `n` one-millisecond readings of joints 1-3 (position, effort), and the truth.
    fn average(&mut self, n: u64) -> ([f64; 3], [f64; 3], [f64; 7]) {
        let (mut p, mut e) = ([0.0; 3], [0.0; 3]);
        for _ in 0..n {
            self.run(1);
            for j in 0..3 {
                p[j] += self.sample.position[j] / n as f64;
                e[j] += self.sample.effort[j] / n as f64;
            }
        }
        (p, e, self.emu().psm().truth().q_true)
    }
}

/// The paper's clamp procedure (section 3): step one joint until |tau_ext| > 1 N·m, reverse
/// until |tau_ext| > 1 N·m the other way, come back; average 20 readings per step.
fn clamp_sweep(joint: usize) -> (f64, f64, usize) {
    let sc = scenario("clamp.toml");
    let mut rig = Rig::new(&sc);
    let model = true_model(rig.emu().psm());
    let q0 = sc.initial_position[joint];
    let step = 0.25e-3 / sc.initial_position[2]; // 0.25 mm at the tip
    let (mut worst_corrected, mut worst_raw, mut active_points): (f64, f64, usize) = (0.0, 0.0, 0);
    let mut sp = q0;
    for (dir, until_back) in [(1.0, false), (-1.0, false), (1.0, true)] {
        loop {
            sp += dir * step;
            rig.emu().psm_mut().set_setpoint(joint, sp);
            rig.run(300);
            let (p, e, q_true) = rig.average(20);
            let c = model.correct(&p, &e);
            let tau_ext = c.tau_ext_nm[joint];
            if c.active[joint] {
                active_points += 1;
                worst_corrected = worst_corrected.max((c.position[joint] - q_true[joint]).abs());
                worst_raw = worst_raw.max((p[joint] - q_true[joint]).abs());
            }
            if (!until_back && tau_ext * dir > 1.0) || (until_back && sp >= q0) {
                break;
            }
        }
    }
    (worst_corrected, worst_raw, active_points)
}

#[test]
fn clamp_corrected_joint_1_matches_the_true_shaft_angle() {
    let (corrected, raw, n) = clamp_sweep(0);
    println!(
        "joint 1 clamp: {n} corrected points, max |q_hat - q_true| = {corrected:.2e} rad, max |q - q_true| = {raw:.2e} rad"
    );
    assert!(n > 40, "{n}");
    assert!(corrected < 3e-4, "corrected {corrected}");
    assert!(raw > 0.05, "uncorrected {raw}");
}

#[test]
fn clamp_corrected_joint_2_matches_the_true_shaft_angle() {
    let (corrected, raw, n) = clamp_sweep(1);
    println!(
        "joint 2 clamp: {n} corrected points, max |q_hat - q_true| = {corrected:.2e} rad, max |q - q_true| = {raw:.2e} rad"
    );
    assert!(n > 30, "{n}");
    assert!(corrected < 3e-4, "corrected {corrected}");
    assert!(raw > 0.03, "uncorrected {raw}");
}

/// Figs. 7-8: pushing in a divot, the uncorrected positions swing while the corrected ones stay
/// at the true (constant) shaft angle.
#[test]
fn divot_push_corrected_positions_stay_put() {
    let sc = scenario("divot-push.toml");
    let mut rig = Rig::new(&sc);
    let model = true_model(rig.emu().psm());
    rig.run(2_000);
    let (mut raw_lo, mut raw_hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let mut worst = [0.0f64; 2];
    let mut active = [0usize; 2];
    for _ in 0..2_000 {
        let (p, e, q_true) = rig.average(10);
        let c = model.correct(&p, &e);
        for j in 0..2 {
            raw_lo[j] = raw_lo[j].min(p[j]);
            raw_hi[j] = raw_hi[j].max(p[j]);
            if c.active[j] {
                active[j] += 1;
                worst[j] = worst[j].max((c.position[j] - q_true[j]).abs());
            }
        }
    }
    for j in 0..2 {
        let swing = raw_hi[j] - raw_lo[j];
        println!(
            "divot push joint {}: uncorrected swing {swing:.3e} rad, corrected max error {:.2e} rad over {} samples",
            j + 1,
            worst[j],
            active[j]
        );
        assert!(swing > 0.1, "joint {}: swing {swing}", j + 1);
        assert!(
            worst[j] < 1e-3,
            "joint {}: corrected error {}",
            j + 1,
            worst[j]
        );
        assert!(active[j] > 500);
    }
}

#[test]
fn fixed_seed_gives_identical_replies_and_other_seeds_differ() {
    let io = io_config();
    let sc = scenario("divot-push.toml");
    let run = |seed: u64| {
        let mut sc = sc.clone();
        sc.seed = seed;
        let mut emu = Emulator::new(&sc, &io).unwrap();
        emu.advance_to(0);
        let mut port = sim_port(&sc, &io).unwrap();
        let mut out = vec![0u8; MAX_REPLY_BYTES];
        let mut log = Vec::new();
        // The same request stream into both an emulator and a port's emulator.
        for k in 1..=300u64 {
            emu.advance_to(k * 3 * NS_PER_MS);
            let req = {
                use dvrk_io::wire::{ControlWord, EthRequest, RequestKind, RequestRepr};
                let mut b = [0u8; 32];
                let r = RequestRepr::host(6, (k % 64) as u8, 0x10, RequestKind::QuadletRead);
                let n = EthRequest::emit(&mut b, ControlWord::new(true, 0), &r, &[]).unwrap();
                b[..n].to_vec()
            };
            let n = emu.handle(&req, &mut out).unwrap();
            log.extend_from_slice(&out[..n]);
        }
        port.link_mut().advance_to(0);
        (log, emu.psm().truth())
    };
    let (a, ta) = run(7);
    let (b, tb) = run(7);
    let (c, _) = run(8);
    assert_eq!(a, b);
    assert_eq!(ta, tb);
    assert_ne!(a, c, "current noise depends on the seed");
}
