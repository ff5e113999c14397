//! The invariant most fuzz targets check, written once: arbitrary bytes, split at a
//! fuzzer-chosen point (the first byte's value), decode exactly like the unsplit stream with
//! the same counters, never panic, and every decoded frame re-encodes to bytes that decode
//! back to the same frame. Frames are compared through Debug, since values may be NaN, which
//! is not equal to itself.

// Every target includes this module and uses one of its two entry points.
#![allow(dead_code)]

use imulab_drivers::codec::{Decoder, Encoder};
use std::fmt::Debug;

pub fn split_and_reencode<D, E>(data: &[u8], new_decoder: impl Fn() -> D, encoder: &E)
where
    D: Decoder,
    D::Frame: Debug,
    E: Encoder<Frame = D::Frame>,
{
    split_and_reencode_as(data, new_decoder, encoder, |frame| format!("{frame:?}"));
}

/// Like [`split_and_reencode`], for protocols whose re-encoded frame legitimately differs
/// from the decoded one: `expected` gives the Debug text the re-decoded frame must have
/// (e.g. Xbus items the decoder skipped are not re-encoded).
pub fn split_and_reencode_as<D, E>(
    data: &[u8],
    new_decoder: impl Fn() -> D,
    encoder: &E,
    expected: impl Fn(&D::Frame) -> String,
) where
    D: Decoder,
    D::Frame: Debug,
    E: Encoder<Frame = D::Frame>,
{
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = new_decoder();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = new_decoder();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    assert_eq!(format!("{whole_frames:?}"), format!("{part_frames:?}"));
    assert_eq!(whole.stats(), parts.stats());

    for frame in &whole_frames {
        let mut bytes = Vec::new();
        if encoder.encode(frame, &mut bytes).is_ok() {
            let mut again = new_decoder();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            assert_eq!(frames.len(), 1, "{frame:?} re-encoded as {bytes:?}");
            assert_eq!(format!("{:?}", frames[0]), expected(frame));
        }
    }
}
