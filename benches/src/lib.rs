//! Workspace-level benchmarks live in `benches/`; per-crate benches live in each crate.
