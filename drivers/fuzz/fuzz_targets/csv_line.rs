//! Fuzz target for the CSV line decoder (default column map): the split-and-re-encode
//! invariant of [`common::split_and_reencode`].
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::csv_line::{CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use libfuzzer_sys::fuzz_target;

fn decoder() -> CsvLineDecoder {
    CsvLineDecoder::new(CsvLineConfig::default()).expect("default config is valid")
}

fuzz_target!(|data: &[u8]| {
    let encoder = CsvLineEncoder::new(CsvLineConfig::default()).expect("default config is valid");
    common::split_and_reencode(data, decoder, &encoder);
});
