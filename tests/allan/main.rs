//! allan integration tests, one binary (fewer, smaller links).

mod fit;
mod logger_csv;
mod plots;
mod reference;
mod report;
mod robustness;
mod session;
mod stable32;
