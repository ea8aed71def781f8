//! The real-time feedback block of one board (reference §2), for every firmware revision and
//! board kind: the first input byte picks the layout, the rest is the block. Checks that every
//! accessor is total, that the block emitters rebuild the same bytes from the decoded fields, and
//! that the raw-to-SI conversion of a real config (exclusive and shared mode) gives finite values.
#![no_main]

#[path = "common.rs"]
mod common;

use dvrk_io::convert::{SharedRaw, decode_blocks, decode_shared};
use dvrk_io::wire::FeedbackBlock;
use dvrk_io::{ArmSample, MAX_BOARDS, NUM_JOINTS};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, bytes)) = data.split_first() else {
        return;
    };
    let lay = common::layout(sel);
    let Ok(b) = FeedbackBlock::new_checked(bytes, lay) else {
        assert!(
            bytes.len() < lay.len_bytes(),
            "a long enough block is accepted"
        );
        return;
    };

    // Every field through its decoder, then back through its emitter.
    let mut out = vec![0u8; lay.len_bytes()];
    let mut e = FeedbackBlock::new_checked(&mut out[..], lay).expect("sized for the layout");
    e.set_timestamp(b.timestamp());
    e.set_status(b.status().raw);
    e.set_digital_io(b.digital_io());
    e.set_temperature(b.temperature());
    let t = b.temperature();
    let _ = (
        t.sensor_celsius(0),
        t.sensor_celsius(1),
        t.sensor_celsius(2),
    );
    let _ = b.timestamp().elapsed_s();
    for m in 0..lay.num_motors() + 2 {
        let adc = b.adc(m);
        assert_eq!(adc.is_some(), m < lay.num_motors());
        if let Some(a) = adc {
            let _ = (a.qla_current_amps(), a.qla_pot_volts());
            e.set_adc(m, a).expect("motor index in range");
        }
        match b.motor_status(m) {
            Some(ms) => {
                assert!(lay.has_motor_status() && m < lay.num_motors());
                let _ = (ms.amp_on(), ms.amp_fault(), ms.mode(), ms.drac_fault_code());
                e.set_motor_status(m, ms.raw).expect("motor index in range");
            }
            None => assert!(!lay.has_motor_status() || m >= lay.num_motors()),
        }
    }
    for i in 0..lay.num_encoders() + 2 {
        let all = (
            b.encoder_position(i),
            b.encoder_period(i),
            b.qtr1(i),
            b.qtr5(i),
            b.running(i),
        );
        let in_range = i < lay.num_encoders();
        match all {
            (Some(p), Some(v), Some(q1), Some(q5), Some(r)) if in_range => {
                let counts = p.counts();
                assert!(
                    (-0x80_0000..0x80_0000).contains(&counts),
                    "24-bit counts {counts}"
                );
                let vel = v.velocity_counts_per_s(lay.velocity_clock_hz());
                assert!(vel.is_finite(), "velocity {vel} from {:#010x}", v.0);
                e.set_encoder_position(i, p)
                    .expect("encoder index in range");
                e.set_encoder_period(i, v).expect("encoder index in range");
                e.set_qtr1(i, q1).expect("encoder index in range");
                e.set_qtr5(i, q5).expect("encoder index in range");
                e.set_running(i, r).expect("encoder index in range");
            }
            (None, None, None, None, None) if !in_range => {}
            other => panic!(
                "encoder {i} of {}: partial fields {other:?}",
                lay.num_encoders()
            ),
        }
    }
    assert_eq!(
        &out[..],
        &bytes[..lay.len_bytes()],
        "emitters rebuild the block that was decoded"
    );

    // Conversion to SI with a real config of this board kind: both boards get this block.
    let cfg = common::io_config(lay.kind());
    let blocks: [Option<FeedbackBlock<&[u8]>>; MAX_BOARDS] = [Some(b), Some(b)];
    let mut s = ArmSample::default();
    let act = decode_blocks(cfg, &blocks, 1, &mut s);
    assert!(s.valid, "every board present and every axis in range");
    for j in 0..NUM_JOINTS {
        for (what, v) in [
            ("position", s.position[j]),
            ("velocity", s.velocity[j]),
            ("effort", s.effort[j]),
            ("actuator current", act.current_amps[j]),
        ] {
            assert!(v.is_finite(), "joint {j} {what} = {v}");
        }
    }

    // Shared mode reads the same registers one quadlet at a time.
    let mut raw = SharedRaw::default();
    for (slot, st) in raw.status.iter_mut().enumerate() {
        *st = (slot < cfg.board_ids().len()).then(|| b.status().raw);
    }
    for (i, a) in cfg.actuators().iter().enumerate() {
        let axis = usize::from(a.axis);
        raw.adc[i] = b.adc(axis).map(|x| x.0);
        raw.encoder_position[i] = b.encoder_position(axis).map(|x| x.0);
    }
    let mut s = ArmSample::default();
    decode_shared(cfg, &raw, 1, &mut s);
    assert!(s.valid);
    assert!(s.position.iter().chain(&s.effort).all(|v| v.is_finite()));
});
