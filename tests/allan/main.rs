//! allan integration tests, one binary (fewer, smaller links).

mod fit;
mod logger_csv;
mod plots;
mod reference;
mod report;
#[path = "../../benches/support/results.rs"]
mod results;
mod robustness;
mod session;
mod stable32;
