//! daemon integration tests, one binary (fewer, smaller links).

mod binary;
use imulab_test_support::daemon_support as common;
mod config;
mod disk;
mod end_to_end;
mod host_check;
mod pipeline;
mod pty;
mod replay;
mod serial;
mod store;
mod ubx_esf;
mod vectornav_mip;
