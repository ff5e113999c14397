//! allan integration tests, one binary (fewer, smaller links).

mod fit;
mod plots;
mod reference;
mod robustness;
mod session;
