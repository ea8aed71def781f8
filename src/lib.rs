//! End-to-end tests, benchmarks and examples of dvrk-sidecar live in tests/, benches/, examples/.
