//! Fuzz target for the Xbus decoder: arbitrary bytes, split at a fuzzer-chosen point, must
//! decode exactly like the unsplit stream, never panic, and every decoded frame must
//! re-encode to bytes that decode back to the same frame.
#![no_main]

use imulab_drivers::codec::xbus::{XbusDecoder, XbusEncoder, XbusMessage};
use imulab_drivers::codec::{Decoder, Encoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut whole = XbusDecoder::new();
    let mut whole_frames = Vec::new();
    whole.decode(data, |f| whole_frames.push(f));

    let mut parts = XbusDecoder::new();
    let mut part_frames = Vec::new();
    parts.decode(&data[..split], |f| part_frames.push(f));
    parts.decode(&data[split..], |f| part_frames.push(f));
    // Compare through Debug: values may be NaN, which is not equal to itself.
    assert_eq!(format!("{whole_frames:?}"), format!("{part_frames:?}"));
    assert_eq!(whole.stats(), parts.stats());

    for frame in &whole_frames {
        let mut bytes = Vec::new();
        if XbusEncoder.encode(frame, &mut bytes).is_ok() {
            let mut again = XbusDecoder::new();
            let mut frames = Vec::new();
            again.decode(&bytes, |f| frames.push(f));
            // Items the decoder skipped are not re-encoded, so compare without that count.
            let expected = match frame {
                XbusMessage::MtData2 { bus_id, data } => XbusMessage::MtData2 {
                    bus_id: *bus_id,
                    data: imulab_drivers::codec::xbus::MtData2 {
                        skipped_items: 0,
                        ..*data
                    },
                },
                other => other.clone(),
            };
            assert_eq!(format!("{frames:?}"), format!("{:?}", [expected]));
        }
    }
});
