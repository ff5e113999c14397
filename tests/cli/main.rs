//! cli integration tests, one binary (fewer, smaller links).

mod decode;
mod demo;
mod errors;
mod interface;
mod pipe;
