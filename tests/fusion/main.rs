//! fusion integration tests, one binary (fewer, smaller links).

mod consumer;
mod filter;
mod fuzz;
mod heading;
mod kfgins;
mod mechanisation;
mod noise;
mod session;
mod stability;
mod study;
use imulab_test_support::fusion_data as support;
