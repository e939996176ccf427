//! The Rust core's integration tests, without Python (`cargo test`, `make test-rust`). One test
//! binary with a module per topic rather than one binary per file: each binary linked the core,
//! its dependencies and proptest again, and instantiated the shared helpers and proptest's
//! generics again (bench/results/test_suite_cpu_rust3.txt). Test names are `module::test`, so
//! `cargo test gradients::` runs one topic.

mod common;

mod batch;
mod errors;
mod gradients;
mod musts;
mod smoke;
mod vector_math;
