//! Fuzz target for the mixed NMEA + UBX decoder: arbitrary bytes, split at a fuzzer-chosen
//! point, must give exactly the frames (messages and merged fixes) and counters of the
//! unsplit stream, never panic, and keep its buffer bounded.
#![no_main]

use imulab_drivers::codec::gnss::GnssDecoder;
use imulab_drivers::codec::Decoder;
use libfuzzer_sys::fuzz_target;

fn run(chunks: &[&[u8]]) -> (Vec<String>, imulab_drivers::DecoderStats) {
    let mut decoder = GnssDecoder::new();
    let mut frames = Vec::new();
    for chunk in chunks {
        decoder.decode(chunk, |f| frames.push(format!("{f:?}")));
    }
    while let Some(f) = decoder.finish() {
        frames.push(format!("{f:?}"));
    }
    (frames, decoder.stats())
}

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let whole = run(&[data]);
    let parts = run(&[&data[..split], &data[split..]]);
    assert_eq!(whole, parts);
});
