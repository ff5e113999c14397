//! Fuzz target for the MIP decoder: the split-and-re-encode invariant of
//! [`common::split_and_reencode`] (IMU packets with fields the decoder does not keep are not
//! encodable and are skipped by it).
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::mip::{MipDecoder, MipEncoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    common::split_and_reencode(data, MipDecoder::new, &MipEncoder);
});
