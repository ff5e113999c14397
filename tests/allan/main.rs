//! allan integration tests, one binary (fewer, smaller links).

mod fit;
mod reference;
mod robustness;
mod session;
