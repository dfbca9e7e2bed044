//! The `insuwb` command line.
fn main() {}
