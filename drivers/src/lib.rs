//! imulab-drivers: sans-IO protocol codecs for inertial sensors and GNSS receivers, and thin
//! async transports that feed them.
//!
//! The split follows quinn-proto/h2: [`codec`] turns bytes into typed frames and back with no
//! I/O, no blocking and no panics; [`transport`] moves bytes between a device (serial port,
//! SocketCAN, slcan adapter, TCP, file replay) and a codec. Every decoder has an encoder, so
//! the simulator speaks each device's own protocol. The transports are the default `transport`
//! feature; `default-features = false` builds the codecs alone (as the fuzz targets do).

pub mod codec;
#[cfg(feature = "transport")]
pub mod transport;
pub mod types;

pub use types::{DecoderStats, GnssFix, ImuSample};
