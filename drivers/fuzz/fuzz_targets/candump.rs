//! Fuzz target for the candump log decoder: the split-and-re-encode invariant of
//! [`common::split_and_reencode`].
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::candump::{CandumpDecoder, CandumpEncoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    common::split_and_reencode(data, CandumpDecoder::new, &CandumpEncoder);
});
