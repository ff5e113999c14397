//! Thin async transports that move bytes between a device and a codec.
