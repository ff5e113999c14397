//! Fuzz target for the VectorNav decoder: the split-and-re-encode invariant of
//! [`common::split_and_reencode_as`]. Binary packets re-encode exactly; ASCII values are
//! re-encoded with the encoder's fixed decimals, so the re-decoded sentence carries the
//! values rounded to those decimals.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::vectornav::{VnDecoder, VnEncoder, VnFrame};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

/// What a re-decoded frame must be: for ASCII, the frame the encoder's text of it decodes
/// to, which must itself be a fixed point of encode + decode.
fn expected(frame: &VnFrame) -> String {
    match frame {
        VnFrame::Ascii(_) => {
            let once = reencoded(frame);
            let twice = reencoded(&once);
            assert_eq!(format!("{once:?}"), format!("{twice:?}"));
            format!("{once:?}")
        }
        other => format!("{other:?}"),
    }
}

fn reencoded(frame: &VnFrame) -> VnFrame {
    let mut bytes = Vec::new();
    VnEncoder.encode(frame, &mut bytes).expect("encodable");
    let mut d = VnDecoder::new();
    let mut frames = Vec::new();
    d.decode(&bytes, |f| frames.push(f));
    assert_eq!(frames.len(), 1);
    frames.remove(0)
}

fuzz_target!(|data: &[u8]| {
    common::split_and_reencode_as(data, VnDecoder::new, &VnEncoder, expected);
});
