//! Fuzz target for the NMEA decoder: the split-and-re-encode invariant of
//! [`common::split_and_reencode`].
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::nmea::{NmeaDecoder, NmeaEncoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    common::split_and_reencode(data, NmeaDecoder::new, &NmeaEncoder);
});
