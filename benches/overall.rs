//! Overall-strategy benchmarks.
fn main() {}
