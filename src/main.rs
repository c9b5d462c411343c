//! The `snakectl` command line.
fn main() {}
