//! Helpers shared by the IMU/CAN codec tests: build a stream of encoded frames between
//! garbage, decode it split at every byte boundary and compare with the expected frames.

#![allow(dead_code)]

use imulab_drivers::codec::{Decoder, Encoder};

/// Pushes `bytes` in one go and polls until the decoder is empty.
pub fn decode_all<D: Decoder>(decoder: &mut D, bytes: &[u8]) -> Vec<D::Frame> {
    decoder.push(bytes);
    std::iter::from_fn(|| decoder.poll()).collect()
}

/// Pushes `bytes` split in two at `split`, polling after each part.
pub fn decode_split<D: Decoder>(mut decoder: D, bytes: &[u8], split: usize) -> (Vec<D::Frame>, D) {
    let mut frames = decode_all(&mut decoder, &bytes[..split]);
    frames.extend(decode_all(&mut decoder, &bytes[split..]));
    (frames, decoder)
}

/// Checks that every split of `bytes` decodes to `expected`; returns the decoder of the
/// unsplit run for counter checks.
pub fn assert_every_split<D, F>(make: impl Fn() -> D, bytes: &[u8], expected: &[F]) -> D
where
    D: Decoder<Frame = F>,
    F: PartialEq + std::fmt::Debug,
{
    for split in 0..=bytes.len() {
        let (frames, _) = decode_split(make(), bytes, split);
        assert_eq!(frames, expected, "split at byte {split} of {}", bytes.len());
    }
    // Byte by byte, the worst case for partial frames.
    let mut decoder = make();
    let mut frames = Vec::new();
    for b in bytes {
        frames.extend(decode_all(&mut decoder, std::slice::from_ref(b)));
    }
    assert_eq!(frames, expected, "byte-by-byte feed");
    let (_, decoder) = decode_split(make(), bytes, bytes.len());
    decoder
}

/// The stream of `items` (garbage, then one encoded frame each) followed by `tail`: its
/// bytes, the frames in order, and how many of its bytes are garbage.
pub fn stream_with_garbage<E>(
    encoder: &E,
    items: &[(Vec<u8>, E::Frame)],
    tail: &[u8],
) -> (Vec<u8>, Vec<E::Frame>, usize)
where
    E: Encoder,
    E::Frame: Clone,
{
    let mut bytes = Vec::new();
    let mut garbage_len = tail.len();
    for (garbage, frame) in items {
        bytes.extend_from_slice(garbage);
        garbage_len += garbage.len();
        encoder.encode(frame, &mut bytes).expect("valid");
    }
    bytes.extend_from_slice(tail);
    let frames = items.iter().map(|(_, frame)| frame.clone()).collect();
    (bytes, frames, garbage_len)
}
