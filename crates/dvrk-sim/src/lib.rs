//! dvrk-sim
