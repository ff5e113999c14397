//! Fuzz target for the WitMotion packet decoder: arbitrary bytes, split at a fuzzer-chosen point, must
//! decode exactly like the unsplit stream, never panic, and every decoded frame must
//! re-encode to bytes that decode back to the same frame.
#![no_main]

use imulab_drivers::codec::witmotion::{WitDecoder, WitEncoder};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = WitDecoder::new();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = WitDecoder::new();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    // Compare through Debug: values may be NaN, which is not equal to itself.
    assert_eq!(format!("{whole_frames:?}"), format!("{part_frames:?}"));
    assert_eq!(whole.stats(), parts.stats());

    for frame in &whole_frames {
        let mut bytes = Vec::new();
        if WitEncoder.encode(frame, &mut bytes).is_ok() {
            let mut again = WitDecoder::new();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            assert_eq!(
                format!("{:?}", frames.as_slice()),
                format!("{:?}", std::slice::from_ref(frame))
            );
        }
    }
});
