//! dvrk-io
