//! Fuzz target for the Xbus decoder: the split-and-re-encode invariant of
//! [`common::split_and_reencode_as`]; MTData2 items the decoder skipped are not re-encoded,
//! so the re-decoded frame has `skipped_items` 0.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use imulab_drivers::codec::xbus::{MtData2, XbusDecoder, XbusEncoder, XbusMessage};
use libfuzzer_sys::fuzz_target;

fn without_skipped_items(frame: &XbusMessage) -> String {
    match frame {
        XbusMessage::MtData2 { bus_id, data } => format!(
            "{:?}",
            XbusMessage::MtData2 {
                bus_id: *bus_id,
                data: MtData2 {
                    skipped_items: 0,
                    ..*data
                },
            }
        ),
        other => format!("{other:?}"),
    }
}

fuzz_target!(|data: &[u8]| {
    common::split_and_reencode_as(data, XbusDecoder::new, &XbusEncoder, without_skipped_items);
});
