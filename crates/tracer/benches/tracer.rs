//! Tracer benchmarks (OWNER: bvh helper).
fn main() {}
