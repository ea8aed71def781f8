//! Hub memory after a broadcast query (reference §3.4). The first input byte gives the number of
//! boards (1..=16) and the second the (firmware, board kind) of their blocks, as discovery
//! would; the rest is the hub memory read back. Checks that every slot's header check and block
//! view are total, that a slot whose header has the layout's size yields a block, and that the
//! hub emitters rebuild the bytes that were read.
#![no_main]

#[path = "common.rs"]
mod common;

use dvrk_io::wire::hub::MAX_HUB_BOARDS;
use dvrk_io::wire::{HubLayout, HubView, WireError};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let [count, sel, bytes @ ..] = data else {
        return;
    };
    let n = usize::from(*count) % MAX_HUB_BOARDS + 1;
    let lay = common::layout(*sel);
    // Ascending board ids ending at 15 (boards 6 and 7 for n = 2 with ids 14, 15: the ids
    // only matter for the mask).
    let ids = (0..n).map(|i| (16 - n + i) as u8);
    let hub = HubLayout::from_boards(ids.map(|id| (id, lay))).expect("at most 16 boards");
    assert_eq!(hub.len_bytes(), n * (lay.len_bytes() + 4) + 4);
    let Ok(v) = HubView::new_checked(bytes, hub) else {
        assert!(bytes.len() < hub.len_bytes());
        return;
    };

    let mut out = vec![0u8; hub.len_bytes()];
    let mut e = HubView::new_checked(&mut out[..], hub).expect("sized for the layout");
    let (start, finish) = v.timing();
    e.set_timing(start, finish);
    for i in 0..n + 1 {
        let header = v.header(i);
        assert_eq!(header.is_some(), i < n);
        let Some(h) = header else {
            assert!(matches!(v.block(i), Err(WireError::IndexOutOfRange { .. })));
            continue;
        };
        let _ = (h.sequence_lsb(), h.sequence_mismatch(), h.update_time());
        e.set_header(i, h).expect("slot in range");
        match v.block(i) {
            Ok(b) => {
                assert_eq!(h.size_quadlets() as usize, lay.len_quadlets() + 1);
                let _ = (b.timestamp(), b.status(), b.adc(0), b.encoder_position(0));
                e.block_mut(i)
                    .expect("slot in range")
                    .into_inner()
                    .copy_from_slice(b.as_bytes());
            }
            Err(WireError::HubBlockSize {
                index,
                got,
                expected,
            }) => {
                assert_eq!(index, i);
                assert_eq!(got, h.size_quadlets());
                assert_ne!(got, expected);
                // Copy the raw slot so the round trip still covers it.
                let off = i * (lay.len_bytes() + 4) + 4;
                e.block_mut(i)
                    .expect("slot in range")
                    .into_inner()
                    .copy_from_slice(&bytes[off..off + lay.len_bytes()]);
            }
            Err(other) => panic!("slot {i}: unexpected error {other}"),
        }
    }
    assert_eq!(
        &out[..],
        &bytes[..hub.len_bytes()],
        "emitters rebuild the hub memory"
    );
});
