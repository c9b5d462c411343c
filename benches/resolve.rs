//! Sequential-strategy benchmarks.
fn main() {}
