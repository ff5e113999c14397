//! store integration tests, one binary (fewer, smaller links).

mod cli;
mod common;
mod python;
mod recover;
mod roundtrip;
