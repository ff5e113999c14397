//! Fuzz target for the UBX decoder: arbitrary bytes, split at a fuzzer-chosen point, must
//! decode exactly like the unsplit stream, never panic, and every decoded message must
//! re-encode to bytes that decode back to the same message.
#![no_main]

use imulab_drivers::codec::ubx::{UbxDecoder, UbxEncoder};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = UbxDecoder::new();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = UbxDecoder::new();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    // Compare through Debug: payload floats may be NaN, which is not equal to itself.
    assert_eq!(format!("{whole_frames:?}"), format!("{part_frames:?}"));
    assert_eq!(whole.stats(), parts.stats());

    for frame in &whole_frames {
        let mut bytes = Vec::new();
        if UbxEncoder.encode(frame, &mut bytes).is_ok() {
            let mut again = UbxDecoder::new();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            assert_eq!(
                format!("{:?}", frames.as_slice()),
                format!("{:?}", std::slice::from_ref(frame))
            );
        }
    }
});
