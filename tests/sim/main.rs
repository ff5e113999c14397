//! sim integration tests, one binary (fewer, smaller links).

mod allan;
mod scenes;
mod serve;
mod session;
use imulab_test_support::allan_check as support;
use imulab_test_support::space;
