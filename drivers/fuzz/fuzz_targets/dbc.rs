//! Fuzz target for IMU over CAN via DBC: arbitrary bytes as a candump log, decoded through
//! the fixture DBC and mapping, must never panic, and split input must give the same samples.
#![no_main]

use imulab_drivers::codec::candump::CandumpDecoder;
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping, DbcStreamDecoder};
use imulab_drivers::codec::Decoder;
use libfuzzer_sys::fuzz_target;

const DBC: &str = include_str!("../../../fixtures/imu_can.dbc");
const MAPPING: &str = include_str!("../../../fixtures/imu_can_mapping.toml");

fn decoder() -> DbcStreamDecoder<CandumpDecoder> {
    let mapping = DbcImuMapping::from_toml_str(MAPPING).expect("fixture mapping");
    let imu = DbcImu::new(DBC, &mapping).expect("fixture DBC");
    DbcStreamDecoder::new(CandumpDecoder::new(), |r| Some(r.frame), imu)
}

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = decoder();
    let mut whole_samples = Vec::new();
    whole.decode(data, |s| whole_samples.push(s));
    whole_samples.extend(whole.finish());

    let mut parts = decoder();
    let mut part_samples = Vec::new();
    parts.decode(&data[..split], |s| part_samples.push(s));
    parts.decode(&data[split..], |s| part_samples.push(s));
    part_samples.extend(parts.finish());
    assert_eq!(format!("{whole_samples:?}"), format!("{part_samples:?}"));
    assert_eq!(whole.stats(), parts.stats());
});
