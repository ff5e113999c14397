//! `imulab`: the offline analyser.
fn main() {}
