//! dvrk-io per-cycle costs:
//! - `decode_qla_rev8_pair`: two QLA Rev 8 feedback blocks (PSM1, boards 6 and 7) into an
//!   `ArmSample` (checked views, raw to SI, 4x4 coupling, health). Goal <= 100 ns.
//! - `udp_quadlet_round_trip`: one quadlet read through `UdpPort` to a responder thread on
//!   127.0.0.1 (request build, send, receive, full reply validation). Criterion reports the mean;
//!   a custom loop timing individual round trips prints p50/p99/max.
//!
//! Run with `cargo bench --bench io`; results go to benches/README.md.

use std::hint::black_box;
use std::net::UdpSocket;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use dvrk_io::ArmSample;
use dvrk_io::convert::decode_blocks;
use dvrk_io::port::{Port, UdpPort};
use dvrk_io::wire::block::{motor_status_bits, status_bits};
use dvrk_io::wire::firewire::node_id;
use dvrk_io::wire::{
    Adc, BlockLayout, BoardKind, BoardStatus, EncoderPeriod, EncoderPosition, EthReply, EthRequest,
    ExtraData, FeedbackBlock, RequestKind, RequestRepr, ResponseKind, ResponseRepr, Timestamp,
};

const PSM_CLASSIC: &str = include_str!("../config/io/psm-classic.toml");

/// A plausible block of one QLA board at Rev 8: powered, amps on, axes moving.
fn qla_block(board: u8, seed: i32) -> Vec<u8> {
    let lay = BlockLayout::new(8, BoardKind::Qla).expect("layout");
    let mut v = vec![0u8; lay.len_bytes()];
    let mut b = FeedbackBlock::new_checked(&mut v[..], lay).expect("block");
    b.set_timestamp(Timestamp(32_767));
    b.set_status(
        BoardStatus::board_id_bits(board)
            | status_bits::MV_GOOD
            | status_bits::POWER_ENABLE
            | status_bits::RELAY_FEEDBACK
            | status_bits::RELAY_COMMANDED
            | 0x0F00,
    );
    for ax in 0..4 {
        let k = seed * 1000 + ax as i32 * 137;
        b.set_encoder_position(ax, EncoderPosition::from_counts(k))
            .expect("axis");
        b.set_encoder_period(
            ax,
            EncoderPeriod::from_velocity(f64::from(k), lay.velocity_clock_hz()),
        )
        .expect("axis");
        b.set_adc(ax, Adc::new(0x8000, (0x8000 + k) as u16))
            .expect("axis");
        b.set_motor_status(ax, motor_status_bits::AMP_ON)
            .expect("axis");
    }
    v
}

fn bench_decode(c: &mut Criterion) {
    let cfg = dvrk_sidecar::formats::io_from_toml(PSM_CLASSIC).expect("psm-classic.toml");
    let lay = BlockLayout::new(8, BoardKind::Qla).expect("layout");
    let b6 = qla_block(6, 3);
    let b7 = qla_block(7, -2);
    let mut out = ArmSample::default();
    let mut t = 0u64;
    c.bench_function("decode_qla_rev8_pair", |b| {
        b.iter(|| {
            t += 666_667;
            let blocks = [
                FeedbackBlock::new_checked(black_box(&b6[..]), lay).ok(),
                FeedbackBlock::new_checked(black_box(&b7[..]), lay).ok(),
            ];
            decode_blocks(&cfg, &blocks, t, &mut out);
            black_box(&out);
        })
    });
}

/// Answers quadlet reads (register value = address) until `stop`.
fn spawn_responder(stop: Arc<AtomicBool>) -> (std::net::SocketAddr, std::thread::JoinHandle<()>) {
    let sock = UdpSocket::bind("127.0.0.1:0").expect("bind");
    sock.set_read_timeout(Some(Duration::from_millis(20)))
        .expect("timeout");
    let addr = sock.local_addr().expect("addr");
    let h = std::thread::spawn(move || {
        let mut rx = [0u8; 2048];
        let mut tx = [0u8; 2048];
        while !stop.load(Ordering::Relaxed) {
            let Ok((n, from)) = sock.recv_from(&mut rx) else {
                continue;
            };
            let Ok(req) = EthRequest::parse(&rx[..n]) else {
                continue;
            };
            let Ok(r) = RequestRepr::parse(&req.packet) else {
                continue;
            };
            if r.kind != RequestKind::QuadletRead {
                continue;
            }
            let node = (r.dest_id & 0x3F) as u8;
            let resp = ResponseRepr {
                dest_id: r.src_id,
                src_id: node_id(node),
                label: r.label,
                rcode: 0,
                kind: ResponseKind::Quadlet {
                    data: r.offset as u32,
                },
            };
            if let Ok(m) = EthReply::emit(
                &mut tx,
                &resp,
                &[],
                &ExtraData {
                    flags: 0x10,
                    ..Default::default()
                },
            ) {
                let _ = sock.send_to(&tx[..m], from);
            }
        }
    });
    (addr, h)
}

fn bench_udp(c: &mut Criterion) {
    let stop = Arc::new(AtomicBool::new(false));
    let (addr, h) = spawn_responder(stop.clone());
    let mut port = UdpPort::open_udp(addr).expect("udp port");
    port.link_mut()
        .set_timeout(Duration::from_millis(100))
        .expect("timeout");
    for _ in 0..1000 {
        port.read_quadlet(6, 0x15).expect("warm-up");
    }
    c.bench_function("udp_quadlet_round_trip", |b| {
        b.iter(|| black_box(port.read_quadlet(6, black_box(0x15)).expect("read")))
    });

    // Individual round trips for the tail.
    const N: usize = 20_000;
    let mut lat = Vec::with_capacity(N);
    for _ in 0..N {
        let t0 = Instant::now();
        let v = port.read_quadlet(6, 0x15).expect("read");
        lat.push(t0.elapsed());
        black_box(v);
    }
    lat.sort_unstable();
    let pct = |p: f64| lat[((N as f64 * p) as usize).min(N - 1)];
    println!(
        "udp_quadlet_round_trip individual ({N} round trips): p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        pct(0.50).as_secs_f64() * 1e6,
        pct(0.99).as_secs_f64() * 1e6,
        lat[N - 1].as_secs_f64() * 1e6
    );
    stop.store(true, Ordering::Relaxed);
    let _ = h.join();
}

criterion_group!(benches, bench_decode, bench_udp);
criterion_main!(benches);
