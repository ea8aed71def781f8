//! A virtual-fixture consumer of dvrk-sidecar: waits for every compensated tip pose and computes
//! the signed distance of the tip to a forbidden-region plane, printing when the tip would cross
//! it. It also reads the raw (uncompensated) pose of the same cycle, to show how far the two
//! disagree while the instrument pushes on something.
//!
//! ```text
//! cargo run --release -p virtual-fixture --example virtual_fixture -- --prefix PSM1 \
//!     --point 0,0,-0.12 --normal 0,0,1 --margin 0.001 --count 3000 [--wait predictive]
//! ```
//! The plane is given in the RCM frame (CRTK local/measured_cp) by a point and a normal pointing
//! to the allowed side. `--wait event|spin|predictive` chooses how to wait for poses (see
//! `dvrk_ipc::WaitStrategy`); `--deadline-ms` after how long without a pose the fixture reports
//! a silence (default: dvrk-ipc's, 10 ms at 1500 Hz). This package depends on dvrk-ipc only.

use std::process::ExitCode;

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{
    NOMINAL_PERIOD, PoseV2, ServiceNames, SubscribeOptions, Subscription, Topic, Update,
    WaitStrategy, create_node,
};
use virtual_fixture::{Args, parse_args, signed_distance};

fn main() -> ExitCode {
    let args = match parse_args(std::env::args().skip(1)) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let node = create_node::<Service>("virtual-fixture", None)?;
    let names = ServiceNames::new(&args.prefix)?;
    let options = SubscribeOptions {
        period: NOMINAL_PERIOD,
        wait: args.wait,
        deadline: args.deadline,
        ..SubscribeOptions::default()
    };
    let mut tip = Subscription::<PoseV2, Service>::with_options(
        &node,
        &names,
        Topic::CompensatedLocalMeasuredCp,
        options,
    )?;
    // The raw pose is only looked at when a tip pose came: it never waits, so it needs no
    // listener (a spinning subscription has none and costs the publisher nothing).
    let raw_options = SubscribeOptions {
        wait: WaitStrategy::Spin,
        ..options
    };
    let mut raw = Subscription::<PoseV2, Service>::with_options(
        &node,
        &names,
        Topic::LocalMeasuredCp,
        raw_options,
    )?;
    let mut seen = 0u64;
    let mut inside_margin = false;
    // Report a silent publisher once per episode, not at every missed deadline.
    let mut stale_reported = false;
    while args.count.is_none_or(|n| seen < n) {
        match tip.wait()? {
            Update::Fresh(p) if p.header.valid == 1 => {
                seen += 1;
                if stale_reported {
                    eprintln!("seq {}: poses flow again", p.header.seq);
                    stale_reported = false;
                }
                let d = signed_distance(args, &p.position_m);
                let now_inside = d < args.margin;
                if now_inside != inside_margin {
                    let raw_d = raw_of_cycle(&mut raw, p.header.seq)?
                        .map(|r| signed_distance(args, &r.position_m));
                    let raw_txt = raw_d.map_or(String::new(), |r| {
                        format!(" (uncompensated says {:+.3} mm)", r * 1e3)
                    });
                    if now_inside {
                        println!(
                            "seq {}: tip {:+.3} mm from the plane: would cross, fixture engages{raw_txt}",
                            p.header.seq,
                            d * 1e3
                        );
                    } else {
                        println!(
                            "seq {}: tip {:+.3} mm from the plane: clear again{raw_txt}",
                            p.header.seq,
                            d * 1e3
                        );
                    }
                    inside_margin = now_inside;
                }
            }
            Update::Fresh(p) => eprintln!(
                "seq {}: invalid sample (flags {:#x}), fixture holds",
                p.header.seq, p.header.flags
            ),
            Update::Stale { since_ns } if !stale_reported => {
                eprintln!(
                    "no pose for {:.1} ms: fixture holds until poses flow again",
                    since_ns as f64 / 1e6
                );
                stale_reported = true;
            }
            Update::Stale { .. } => {}
            Update::Terminated if !stale_reported => {
                eprintln!(
                    "publisher of {} is gone: fixture holds until it comes back",
                    tip.service_name()
                );
                stale_reported = true;
            }
            Update::Terminated => {}
            Update::Interrupted => {}
        }
    }
    println!("{seen} compensated poses received");
    Ok(())
}

/// The uncompensated pose of cycle `seq`. The sidecar wakes the tip pose's subscribers right
/// after that first message of the cycle and writes the uncompensated pose a few microseconds
/// later, so this polls for it (`raw` spins); only called when the fixture engages or clears.
/// Every sample drained on the way is looked at, not only the newest: a subscription that just
/// connected gets the previous cycle's sample and the next one together. `None` if that cycle's
/// pose was not published (an invalid cycle, a stopped sidecar) or was drained by an earlier call.
fn raw_of_cycle(
    raw: &mut Subscription<PoseV2, Service>,
    seq: u64,
) -> Result<Option<PoseV2>, Box<dyn std::error::Error>> {
    let mut found = raw.latest().filter(|r| r.header.seq == seq).copied();
    let mut newest = raw.latest().map_or(0, |r| r.header.seq);
    while newest < seq {
        let update = raw.wait_with(|r| {
            if r.header.seq == seq {
                found = Some(*r);
            }
        })?;
        match update {
            Update::Fresh(r) => newest = r.header.seq,
            _ => break,
        }
    }
    Ok(found)
}
