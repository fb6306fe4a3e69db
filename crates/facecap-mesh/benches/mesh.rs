//! Criterion benches of the mesh front end (filled in below).
fn main() {}
