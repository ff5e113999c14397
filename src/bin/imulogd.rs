//! `imulogd`: the acquisition daemon.
fn main() {}
