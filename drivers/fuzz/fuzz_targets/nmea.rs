//! Fuzz target for the NMEA decoder: arbitrary bytes, split at a fuzzer-chosen point, must
//! decode exactly like the unsplit stream, never panic, and every decoded sentence must
//! re-encode to bytes that decode back to the same sentence.
#![no_main]

use imulab_drivers::codec::nmea::{NmeaDecoder, NmeaEncoder};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = NmeaDecoder::new();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = NmeaDecoder::new();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    assert_eq!(whole_frames, part_frames);
    assert_eq!(whole.stats(), parts.stats());

    for frame in &whole_frames {
        let mut bytes = Vec::new();
        if NmeaEncoder.encode(frame, &mut bytes).is_ok() {
            let mut again = NmeaDecoder::new();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            assert_eq!(frames.as_slice(), std::slice::from_ref(frame));
        }
    }
});
