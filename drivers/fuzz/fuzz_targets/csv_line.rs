//! Fuzz target for the CSV line decoder (default column map): arbitrary bytes, split at a
//! fuzzer-chosen point, must decode exactly like the unsplit stream and never panic; every
//! decoded sample must re-encode to a line that decodes back to the same sample.
#![no_main]

use imulab_drivers::codec::csv_line::{CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

fn decoder() -> CsvLineDecoder {
    CsvLineDecoder::new(CsvLineConfig::default()).expect("default config is valid")
}

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = decoder();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = decoder();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    assert_eq!(whole_frames, part_frames);
    assert_eq!(whole.stats(), parts.stats());

    let encoder = CsvLineEncoder::new(CsvLineConfig::default()).expect("valid");
    for sample in &whole_frames {
        let mut bytes = Vec::new();
        if encoder.encode(sample, &mut bytes).is_ok() {
            let mut again = decoder();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            assert_eq!(frames.as_slice(), std::slice::from_ref(sample));
        }
    }
});
