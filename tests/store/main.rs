//! store integration tests, one binary (fewer, smaller links).

mod cli;
mod common;
mod events;
mod faults;
mod journal;
mod python;
mod recover;
#[path = "../../benches/support/results.rs"]
mod results;
mod rotation;
mod roundtrip;
use imulab_test_support::space;
