//! sim integration tests, one binary (fewer, smaller links).

mod allan;
mod scenes;
mod serve;
mod session;
#[path = "../store/space.rs"]
mod space;
mod support;
